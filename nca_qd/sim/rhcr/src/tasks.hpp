// The lifelong task model both simulators share (RHCR's, as the paper ran it): input checks,
// start cells, and each agent's goals drawn from goal classes that cycle.
#pragma once

#include <algorithm>
#include <chrono>
#include <numeric>
#include <random>
#include <stdexcept>
#include <vector>

#include "astar.hpp"
#include "cpu_clock.hpp"
#include "grid.hpp"
#include "rhcr.hpp"
#include "rng.hpp"

namespace rhcr {

// Draws each agent's next goal: class ids cycle, the cell is drawn by the class weights.
class TaskAssigner {
 public:
  TaskAssigner(const SimConfig& cfg, Rng& rng) : cfg_(cfg), rng_(rng) {
    for (const auto& cls : cfg.classes) {
      std::vector<double> cum(cls.weights.size());
      std::partial_sum(cls.weights.begin(), cls.weights.end(), cum.begin());
      cumulative_.push_back(std::move(cum));
    }
  }
  Goal next(int& phase) {
    const int cls_id = cfg_.cycle[phase];
    phase = (phase + 1) % static_cast<int>(cfg_.cycle.size());
    const auto& cum = cumulative_[cls_id];
    const double u = rng_.uniform() * cum.back();
    size_t i = std::upper_bound(cum.begin(), cum.end(), u) - cum.begin();
    if (i >= cum.size()) i = cum.size() - 1;
    return {cfg_.classes[cls_id].cells[i], cfg_.classes[cls_id].dwell};
  }

 private:
  const SimConfig& cfg_;
  Rng& rng_;
  std::vector<std::vector<double>> cumulative_;
};

inline void validate(const SimConfig& cfg) {
  const int cells = cfg.rows * cfg.cols;
  if (cfg.rows <= 0 || cfg.cols <= 0 || static_cast<int>(cfg.traversable.size()) != cells)
    throw std::invalid_argument("traversable mask does not match rows x cols");
  if (cfg.horizon <= 0) throw std::invalid_argument("horizon T must be positive");
  if (cfg.n_agents <= 0) throw std::invalid_argument("need at least one agent");
  if (cfg.window < 1 || cfg.replan < 1 || cfg.replan > cfg.window)
    throw std::invalid_argument("need 1 <= replan (h) <= window (w)");
  if (cfg.cycle.empty()) throw std::invalid_argument("empty goal cycle");
  for (int id : cfg.cycle)
    if (id < 0 || id >= static_cast<int>(cfg.classes.size())) throw std::invalid_argument("bad class id in cycle");
  for (const auto& cls : cfg.classes) {
    if (cls.cells.empty() || cls.cells.size() != cls.weights.size())
      throw std::invalid_argument("goal class needs cells with one weight each");
    for (size_t i = 0; i < cls.cells.size(); ++i) {
      if (cls.cells[i] < 0 || cls.cells[i] >= cells || !cfg.traversable[cls.cells[i]])
        throw std::invalid_argument("goal cell off the traversable tiles");
      if (!(cls.weights[i] > 0)) throw std::invalid_argument("goal weights must be positive");
    }
    if (cls.dwell < 0) throw std::invalid_argument("dwell must be >= 0");
  }
  const int n_free = static_cast<int>(std::count(cfg.traversable.begin(), cfg.traversable.end(), 1));
  if (cfg.n_agents > n_free) throw std::invalid_argument("more agents than traversable tiles");
}

// Initial cells: distinct, uniform over traversable tiles (partial Fisher-Yates, per seed);
// or, with reference_starts, the reference's: its traversable cells in row-major order
// shuffled by an unseeded std::default_random_engine, the same for every seed.
inline std::vector<int> start_cells(const SimConfig& cfg, const Grid& grid, Rng& rng) {
  std::vector<int> free_cells;
  for (int c = 0; c < grid.cells(); ++c)
    if (grid.traversable(c)) free_cells.push_back(c);
  if (cfg.reference_starts) std::shuffle(free_cells.begin(), free_cells.end(), std::default_random_engine());
  for (int a = 0; a < cfg.n_agents; ++a)
    if (!cfg.reference_starts) std::swap(free_cells[a], free_cells[a + rng.below(free_cells.size() - a)]);
  free_cells.resize(cfg.n_agents);
  return free_cells;
}

// A run's clocks, the same for both planners: CPU and wall time from its start, and the wall
// deadline of its time limit (none when time_limit_s <= 0).
struct RunClock {
  using clock = std::chrono::steady_clock;
  explicit RunClock(double time_limit_s)
      : cpu0(thread_cpu_seconds()),
        wall0(clock::now()),
        limited(time_limit_s > 0),
        deadline(limited ? wall0 + std::chrono::duration_cast<clock::duration>(std::chrono::duration<double>(time_limit_s))
                         : clock::time_point::max()) {}
  bool expired() const { return limited && clock::now() > deadline; }
  const double cpu0;
  const clock::time_point wall0;
  const bool limited;
  const clock::time_point deadline;
};

// RHCR's congestion rule, the same for both planners: over a round of h executed steps an agent
// is stuck when it stood on one cell, not dwelling at a station, at times t .. t+h-1 of the
// round (the round's last step does not count); the run congests when more than half of the
// agents are stuck at the round's end.
class StuckWatch {
 public:
  explicit StuckWatch(int n_agents) : start_(n_agents), stuck_(n_agents) {}
  // A round begins: each agent's cell and whether it is dwelling at a station now.
  void begin(int agent, int cell, bool tasking) {
    start_[agent] = cell;
    stuck_[agent] = !tasking;
  }
  // Step s (1-based) of a round of h steps put the agent on `cell`.
  void step(int agent, int s, int h, int cell, bool tasking) {
    if (s < h && (cell != start_[agent] || tasking)) stuck_[agent] = 0;
  }
  bool congested() const {
    const int n_stuck = static_cast<int>(std::count(stuck_.begin(), stuck_.end(), 1));
    return 2 * n_stuck > static_cast<int>(stuck_.size());
  }

 private:
  std::vector<int> start_;
  std::vector<char> stuck_;
};

// The end of a run, the same for both planners: the time it stopped at, success (ran to T, not
// congested, not timed out), throughput over T, every agent's goals flattened (goal_offsets[a]
// .. goal_offsets[a + 1] are agent a's, in the order given), and the run's CPU and wall time.
inline void finish_result(SimResult& res, int t, int T, const std::vector<std::vector<Goal>>& goal_log,
                          const RunClock& clock) {
  res.stop_time = t;
  res.success = !res.congested && !res.timed_out && t == T;
  res.throughput = static_cast<double>(res.finished_tasks) / T;
  res.goal_offsets.push_back(0);
  for (const auto& log : goal_log) {
    for (const Goal& g : log) {
      res.goal_cells.push_back(g.cell);
      res.goal_dwell.push_back(g.dwell);
    }
    res.goal_offsets.push_back(static_cast<int32_t>(res.goal_cells.size()));
  }
  res.cpu_seconds = thread_cpu_seconds() - clock.cpu0;
  res.wall_seconds = std::chrono::duration<double>(RunClock::clock::now() - clock.wall0).count();
}

}  // namespace rhcr
