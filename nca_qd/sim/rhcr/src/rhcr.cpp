#include "rhcr.hpp"

#include <algorithm>
#include <chrono>
#include <deque>
#include <numeric>
#include <random>
#include <stdexcept>
#include <string>

#include "cpu_clock.hpp"
#include "grid.hpp"
#include "pbs.hpp"
#include "rng.hpp"
#include "tasks.hpp"

namespace rhcr {
namespace {

// Bound on the goal queue (only reachable when goals of consecutive kinds share cells).
constexpr size_t kMaxQueue = 32;

struct AgentState {
  int cell = 0;
  int phase = 0;            // position in the class cycle of the next goal to draw
  std::deque<Goal> queue;   // upcoming goals, front first
  bool arrived = false;     // standing on queue.front() since arriving (dwell in progress)
  int stayed = 0;           // timesteps stayed on queue.front() after arriving
  bool tasking = false;     // the last executed step was a dwell step at a station
};

}  // namespace

SimResult simulate(const SimConfig& cfg) {
  validate(cfg);
  const RunClock clock(cfg.time_limit_s);

  const int N = cfg.n_agents, T = cfg.horizon, w = cfg.window, h = cfg.replan;
  Grid grid(cfg.rows, cfg.cols, cfg.traversable);
  DistanceCache distances(grid);
  Rng rng(cfg.seed);
  TaskAssigner assigner(cfg, rng);
  WindowedPBS pbs(grid, N, w);
  PbsLimits limits;
  // Automatic node budget: RHCR's 60 s cutoff in the reference's own effort. Its high-level
  // nodes cost 6-26 ms each at 1,400 agents (950-1,920 nodes in 6-50 s per call), so the
  // cutoff admits about 5,000 of them there; a node's cost grows with the number of agents.
  limits.max_nodes = cfg.pbs_max_nodes > 0 ? cfg.pbs_max_nodes
                     : cfg.pbs_max_nodes == 0 ? std::max<int64_t>(1000, 7000000 / N)
                                              : 0;
  limits.time_limit_s = cfg.plan_time_limit_s;
  limits.max_expansions = cfg.plan_max_expansions;
  limits.deadline = clock.deadline;
  limits.prioritize_start = cfg.prioritize_start;
  Rng repair_rng(cfg.seed ^ 0x5DEECE66DULL);  // the failed-call repair's own stream
  bool dwell_goals = false;
  for (const auto& cls : cfg.classes) dwell_goals = dwell_goals || cls.dwell > 0;

  SimResult res;
  res.tasks_per_step.assign(T, 0);
  res.tile_visits.assign(grid.cells(), 0);
  std::vector<std::vector<Goal>> goal_log(N);

  // Initial cells (tasks.hpp): distinct, per seed.
  const std::vector<int> starts = start_cells(cfg, grid, rng);
  std::vector<AgentState> agents(N);
  for (int a = 0; a < N; ++a) agents[a].cell = starts[a];
  // Every agent's first goal is of the cycle's first kind (RHCR: an endpoint in the warehouse,
  // a kind-0 station in manufacturing).

  if (cfg.record_paths) {
    res.paths.reserve(static_cast<size_t>(T + 1) * N);
    for (const auto& ag : agents) res.paths.push_back(ag.cell);
  }

  std::vector<AgentQuery> queries(N);
  std::vector<int> plan;
  StuckWatch watch(N);
  int t = 0;
  while (t < T) {
    if (clock.expired()) {
      res.timed_out = true;
      break;
    }
    // 1. Top up goal queues (RHCR's rule): append while the Manhattan distance from the agent
    //    to its last goal, plus the legs and dwells after it, is <= h; with dwell goals, keep
    //    at least two goals.
    for (int a = 0; a < N; ++a) {
      AgentState& ag = agents[a];
      Goal last = ag.queue.empty() ? Goal{ag.cell, 0} : ag.queue.back();
      int length = grid.manhattan(last.cell, ag.cell) + last.dwell;
      while (ag.queue.empty() ||
             ((length <= h || (dwell_goals && ag.queue.size() < 2)) && ag.queue.size() < kMaxQueue)) {
        const Goal g = assigner.next(ag.phase);
        length += grid.manhattan(g.cell, last.cell) + last.dwell;
        last = g;
        ag.queue.push_back(g);
        goal_log[a].push_back(g);
      }
      AgentQuery& q = queries[a];
      q.start = ag.cell;
      q.start_dwell_left = ag.arrived ? ag.queue.front().dwell - ag.stayed : 0;
      q.goals.assign(ag.queue.begin(), ag.queue.end());
      q.dist.clear();
      for (const Goal& g : ag.queue) q.dist.push_back(distances.get(g.cell));
    }

    // 2. Plan windowed paths (PBS, or its collision-free repair).
    const int steps = std::min(h, T - t);
    for (auto& q : queries) q.min_end = steps;
    const double call_cpu0 = thread_cpu_seconds();
    const int64_t call_nodes0 = pbs.stats().nodes_expanded;
    const int64_t call_expansions0 = pbs.low_level_expansions();
    const bool solved = pbs.solve(queries, steps, limits, repair_rng, plan);
    res.pbs_failures += !solved;
    res.call_failed.push_back(!solved);
    res.call_nodes.push_back(static_cast<int32_t>(pbs.stats().nodes_expanded - call_nodes0));
    res.call_cpu_seconds.push_back(thread_cpu_seconds() - call_cpu0);
    res.call_expansions.push_back(pbs.low_level_expansions() - call_expansions0);
    ++res.replans;
    if (clock.expired()) {  // the call was cut short
      res.timed_out = true;
      break;
    }

    // 3. Execute the first h steps; count goals reached; watch for congestion (StuckWatch).
    for (int a = 0; a < N; ++a) watch.begin(a, agents[a].cell, agents[a].tasking);
    for (int s = 1; s <= steps; ++s) {
      int finished = 0;
      for (int a = 0; a < N; ++a) {
        AgentState& ag = agents[a];
        const int next = plan[a * (w + 1) + s];
        ag.cell = next;
        ag.tasking = false;
        ++res.tile_visits[next];
        if (cfg.record_paths) res.paths.push_back(next);
        // Goal bookkeeping (same rules as the A* model and the Python checker).
        if (ag.queue.empty() || ag.queue.front().cell != ag.cell) {
          ag.arrived = false;
        } else {
          if (ag.arrived) ++ag.stayed, ag.tasking = ag.queue.front().dwell > 0;
          else ag.arrived = true, ag.stayed = 0;
        }
        watch.step(a, s, h, next, ag.tasking);
        while (ag.arrived && ag.stayed >= ag.queue.front().dwell) {
          ag.queue.pop_front();
          ++finished;
          ag.arrived = false;
          if (ag.queue.empty()) {  // cannot happen with the top-up rule; keep the invariant anyway
            const Goal g = assigner.next(ag.phase);
            ag.queue.push_back(g);
            goal_log[a].push_back(g);
          }
          if (ag.queue.front().cell == ag.cell) ag.arrived = true, ag.stayed = 0;
        }
      }
      res.tasks_per_step[t + s - 1] = finished;
      res.finished_tasks += finished;
    }
    t += steps;
    // 4. Congestion: more than half of the agents stuck.
    if (watch.congested()) {
      res.congested = true;
      break;
    }
  }

  res.pbs_nodes = pbs.stats().nodes_expanded;
  res.low_level_expansions = pbs.low_level_expansions();
  finish_result(res, t, T, goal_log, clock);
  return res;
}

}  // namespace rhcr
