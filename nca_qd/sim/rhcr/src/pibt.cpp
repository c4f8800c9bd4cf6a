#include "pibt.hpp"

#include <algorithm>
#include <chrono>
#include <numeric>
#include <vector>

#include "cpu_clock.hpp"
#include "grid.hpp"
#include "rng.hpp"
#include "tasks.hpp"

namespace rhcr {
namespace {

struct Agent {
  int cell = 0;
  int phase = 0;        // position in the class cycle of the next goal to draw
  Goal goal{0, 0};      // the current goal
  const uint16_t* dist = nullptr;  // distances to the goal
  bool arrived = false;  // standing on the goal since arriving (dwell in progress)
  int stayed = 0;        // timesteps stayed on the goal after arriving
  bool tasking = false;  // the last executed step was a dwell step at a station
  int elapsed = 0;       // timesteps since the goal was assigned (the priority)
  double tie = 0;        // the priority's tie-breaker in [0, 1)
};

// One PIBT step: next_[a] for every agent, free of vertex and swap conflicts. With `swap`, the
// step is PIBT with swap (Okumura, "Improving LaCAM for Scalable Eventually Optimal Multi-Agent
// Pathfinding", IJCAI 2023; the planner of LaCAM3): where two agents must pass each other in a
// one-lane corridor, the one asking backs up and pulls the other after it until a branch lets
// them pass; plain PIBT cannot, and on dead ends off one-lane corridors it deadlocks.
class PibtStep {
 public:
  PibtStep(const Grid& grid, std::vector<Agent>& agents, Rng& rng, bool swap)
      : grid_(grid), agents_(agents), rng_(rng), swap_(swap), now_(grid.cells(), -1),
        taken_(grid.cells(), -1), next_(agents.size(), -1) {}

  // Plans the step; returns next cells (indexed by agent).
  const std::vector<int>& plan(const std::vector<int>& order) {
    const int n = static_cast<int>(agents_.size());
    for (int a = 0; a < n; ++a) now_[agents_[a].cell] = a, next_[a] = -1;
    for (int a = 0; a < n; ++a) {  // a dwelling agent stays where it is, whoever asks
      const Agent& ag = agents_[a];
      if (ag.arrived && ag.stayed < ag.goal.dwell) reserve(a, ag.cell);
    }
    for (int a : order)
      if (next_[a] < 0) push(a, -1);
    for (int a = 0; a < n; ++a) now_[agents_[a].cell] = -1, taken_[next_[a]] = -1;
    return next_;
  }

 private:
  void reserve(int a, int cell) {
    taken_[cell] = a;
    next_[a] = cell;
  }

  // PIBT(i, j): agent i chooses a cell, j (or -1) is the agent that asked it to move.
  bool push(int i, int asker) {
    const Agent& ag = agents_[i];
    int cand[5];
    int k = 0;
    for (int d = 0; d < 4; ++d) {
      const int v = grid_.neighbor(ag.cell, d);
      if (v >= 0) cand[k++] = v;
    }
    cand[k++] = ag.cell;
    // Random order first, then a stable sort on distance to goal and (plain PIBT) occupied
    // now: ties among equally near cells fall randomly, a free one first in plain PIBT as in
    // its author's pypibt; with swap, at random among all as in LaCAM3 (a random number in
    // [0, 1) added to each distance).
    for (int x = k - 1; x > 0; --x) std::swap(cand[x], cand[rng_.below(x + 1)]);
    const uint16_t* dist = ag.dist;
    std::stable_sort(cand, cand + k, [&](int u, int v) {
      if (dist[u] != dist[v]) return dist[u] < dist[v];
      return !swap_ && (now_[u] < 0) > (now_[v] < 0);
    });
    int pulled = -1;  // with swap: the agent to pull into this agent's cell, if any
    if (swap_ && (pulled = swap_partner(i, cand[0])) >= 0) std::reverse(cand, cand + k);
    for (int x = 0; x < k; ++x) {
      const int v = cand[x];
      if (taken_[v] >= 0) continue;  // vertex conflict
      const int other = now_[v];
      // Swap conflict. Without swap only the asker can be bound for this cell; with swap an
      // agent pulled by another may be too.
      if (swap_ ? other >= 0 && next_[other] == ag.cell : asker >= 0 && v == agents_[asker].cell) continue;
      reserve(i, v);
      if (other >= 0 && other != i && next_[other] < 0 && !push(other, i)) continue;
      if (x == 0 && pulled >= 0 && next_[pulled] < 0 && taken_[ag.cell] < 0) reserve(pulled, ag.cell);
      return true;
    }
    reserve(i, ag.cell);  // no cell: stay (the asker then tries its next cell)
    return false;
  }

  // PIBT with swap: the agent i should swap places with (and so back away from, pulling it
  // along), or -1. `want` is i's preferred cell. Case (a): the agent on `want` must pass i, and
  // a branch ahead lets them; case (c), clearing the way: a neighbour of i would have to pass i
  // once i steps onto `want`.
  int swap_partner(int i, int want) const {
    const int here = agents_[i].cell;
    if (want == here) return -1;
    const int j = now_[want];
    if (j >= 0 && j != i && next_[j] < 0 && swap_required(i, j, here, want) && swap_possible(want, here)) return j;
    for (int d : {3, 1, 2, 0}) {  // left, right, down, up: LaCAM3's order (the first match wins)
      const int u = grid_.neighbor(here, d);
      const int k = u >= 0 && u != want ? now_[u] : -1;
      if (k >= 0 && swap_required(k, i, here, want) && swap_possible(want, here)) return k;
    }
    return -1;
  }

  // The cells next to `at` an agent could pass through, `from` not counted (nor a dead end
  // held by an agent whose goal it is): how many, and one of them.
  int exits(int at, int from, int& one) const {
    int n = 0;
    for (int d = 0; d < 4; ++d) {
      const int u = grid_.neighbor(at, d);
      if (u < 0 || u == from) continue;
      const int a = now_[u];
      if (a >= 0 && agents_[a].goal.cell == u && degree(u) == 1) continue;
      ++n, one = u;
    }
    return n;
  }

  int degree(int cell) const {
    int n = 0;
    for (int d = 0; d < 4; ++d) n += grid_.neighbor(cell, d) >= 0;
    return n;
  }

  // Whether `pusher` (at p) and `puller` (at q, next to p) must swap: walking on from q while
  // that brings the pusher nearer its goal, no branch comes before a dead end, and each wants
  // the other's side.
  bool swap_required(int pusher, int puller, int p, int q) const {
    const uint16_t* dp = agents_[pusher].dist;
    const uint16_t* dq = agents_[puller].dist;
    while (dp[q] < dp[p]) {
      int next = -1;
      const int n = exits(q, p, next);
      if (n >= 2) return false;  // they can pass at q
      if (n <= 0) break;
      p = q, q = next;
    }
    return dq[p] < dq[q] && (dp[p] == 0 || dp[q] < dp[p]);
  }

  // Whether pulling back from q (the puller's side, away from p) reaches a branch where the
  // two can pass, before a dead end.
  bool swap_possible(int p, int q) const {
    const int origin = p;
    while (q != origin) {
      int next = -1;
      const int n = exits(q, p, next);
      if (n >= 2) return true;
      if (n <= 0) return false;
      p = q, q = next;
    }
    return false;
  }

  const Grid& grid_;
  std::vector<Agent>& agents_;
  Rng& rng_;
  const bool swap_;
  std::vector<int> now_, taken_, next_;
};

}  // namespace

SimResult simulate_pibt(const SimConfig& cfg, bool swap) {
  validate(cfg);
  const RunClock clock(cfg.time_limit_s);
  const int N = cfg.n_agents, T = cfg.horizon, h = cfg.replan;
  Grid grid(cfg.rows, cfg.cols, cfg.traversable);
  DistanceCache distances(grid);
  Rng rng(cfg.seed);
  TaskAssigner assigner(cfg, rng);
  const std::vector<int> starts = start_cells(cfg, grid, rng);
  Rng plan_rng(cfg.seed ^ 0x5DEECE66DULL);  // the planner's own stream (tie-breakers)

  SimResult res;
  res.tasks_per_step.assign(T, 0);
  res.tile_visits.assign(grid.cells(), 0);
  std::vector<std::vector<Goal>> goal_log(N);
  std::vector<Agent> agents(N);
  auto assign = [&](int a) {
    Agent& ag = agents[a];
    ag.goal = assigner.next(ag.phase);
    ag.dist = distances.get(ag.goal.cell);
    ag.elapsed = 0;
    goal_log[a].push_back(ag.goal);
  };
  for (int a = 0; a < N; ++a) {
    agents[a].cell = starts[a];
    agents[a].tie = plan_rng.uniform();
    assign(a);  // the cycle's first kind, as in RHCR
  }
  if (cfg.record_paths) {
    res.paths.reserve(static_cast<size_t>(T + 1) * N);
    for (const auto& ag : agents) res.paths.push_back(ag.cell);
  }

  PibtStep step(grid, agents, plan_rng, swap);
  std::vector<int> order(N);
  std::iota(order.begin(), order.end(), 0);
  StuckWatch watch(N);
  int t = 0;
  while (t < T) {
    if (clock.expired()) {
      res.timed_out = true;
      break;
    }
    // A round of h steps, as RHCR's: its congestion rule is checked at the round's end.
    const int steps = std::min(h, T - t);
    for (int a = 0; a < N; ++a) watch.begin(a, agents[a].cell, agents[a].tasking);
    for (int s = 1; s <= steps; ++s) {
      std::sort(order.begin(), order.end(), [&](int x, int y) {
        if (agents[x].elapsed != agents[y].elapsed) return agents[x].elapsed > agents[y].elapsed;
        if (agents[x].tie != agents[y].tie) return agents[x].tie > agents[y].tie;
        return x < y;
      });
      const double call_cpu0 = thread_cpu_seconds();
      const std::vector<int>& next = step.plan(order);
      res.call_cpu_seconds.push_back(thread_cpu_seconds() - call_cpu0);
      res.call_nodes.push_back(0);
      res.call_expansions.push_back(0);
      res.call_failed.push_back(0);
      ++res.replans;
      int finished = 0;
      for (int a = 0; a < N; ++a) {
        Agent& ag = agents[a];
        ag.cell = next[a];
        ag.tasking = false;
        ++ag.elapsed;
        ++res.tile_visits[ag.cell];
        if (cfg.record_paths) res.paths.push_back(ag.cell);
        // Goal bookkeeping: RHCR's rules (and the Python checker's).
        if (ag.goal.cell != ag.cell) {
          ag.arrived = false;
        } else {
          if (ag.arrived) ++ag.stayed, ag.tasking = ag.goal.dwell > 0;
          else ag.arrived = true, ag.stayed = 0;
        }
        watch.step(a, s, h, ag.cell, ag.tasking);
        while (ag.arrived && ag.stayed >= ag.goal.dwell) {
          ++finished;
          ag.arrived = false;
          assign(a);
          if (ag.goal.cell == ag.cell) ag.arrived = true, ag.stayed = 0;
        }
      }
      res.tasks_per_step[t + s - 1] = finished;
      res.finished_tasks += finished;
    }
    t += steps;
    if (watch.congested()) {
      res.congested = true;
      break;
    }
  }

  finish_result(res, t, T, goal_log, clock);
  return res;
}

}  // namespace rhcr
