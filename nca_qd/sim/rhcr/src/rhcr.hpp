// Rolling-Horizon Collision Resolution (Li et al., AAAI 2021): the lifelong MAPF simulator.
//
// Every `replan` (h) timesteps: top up each agent's goal queue, plan windowed collision-free
// paths for the next `window` (w) timesteps with PBS, execute the first h steps, count the
// goals reached, and stop early on congestion. The task model, the goal-queue horizon and the
// congestion rule are those of RHCR's public implementation as the paper ran it.
#pragma once

#include <cstdint>
#include <vector>

#include "astar.hpp"

namespace rhcr {

// A kind of goal (e.g. "endpoint", "workstation", "endpoint next to a kind-0 station"):
// candidate cells with sampling weights, and the dwell time owed on arrival.
struct GoalClass {
  std::vector<int> cells;
  std::vector<double> weights;
  int dwell = 0;
};

struct SimConfig {
  int rows = 0, cols = 0;
  std::vector<uint8_t> traversable;  // rows * cols, row-major
  std::vector<GoalClass> classes;
  std::vector<int> cycle;  // each agent's goals cycle through these class ids
  int n_agents = 0;
  int horizon = 0;  // T
  uint64_t seed = 0;
  int window = 10;   // w
  int replan = 5;    // h
  double time_limit_s = 0;         // whole run, wall-clock seconds; <= 0: none
  double plan_time_limit_s = 60;   // one planning call, CPU seconds (RHCR's cutoffTime); <= 0: none
  int64_t pbs_max_nodes = 0;       // high-level PBS nodes per planning call; 0: automatic
                                   // (7,000,000 / agents, at least 1,000); < 0: none
  int64_t plan_max_expansions = 0; // A* expansions per planning call (a work bound); <= 0: none
  bool prioritize_start = true;    // RHCR's prioritize_start
  bool reference_starts = false;   // start cells as the reference draws them (below)
  bool record_paths = false;
};

struct SimResult {
  int finished_tasks = 0;
  double throughput = 0;
  bool success = false;
  bool congested = false;
  bool timed_out = false;
  int stop_time = 0;
  std::vector<int32_t> tasks_per_step;  // horizon entries; entry t-1 counts goals done at time t
  std::vector<int64_t> tile_visits;     // rows * cols: agent-timesteps on each tile, times 1..stop_time
  std::vector<int32_t> paths;           // (stop_time + 1) * n_agents cells, if recorded
  std::vector<int32_t> goal_offsets;    // n_agents + 1: agent a's goals are [off[a], off[a+1])
  std::vector<int32_t> goal_cells, goal_dwell;  // every goal assigned, in order
  std::vector<int32_t> call_nodes;        // per planning call: high-level PBS nodes expanded
  std::vector<int64_t> call_expansions;   // per planning call: A* expansions
  std::vector<double> call_cpu_seconds;   // per planning call: CPU seconds
  std::vector<uint8_t> call_failed;       // per planning call: 1 if PBS failed (repaired)
  int replans = 0;
  int pbs_failures = 0;
  int64_t pbs_nodes = 0;
  int64_t low_level_expansions = 0;
  double cpu_seconds = 0;
  double wall_seconds = 0;
};

// Runs one simulation. Throws std::invalid_argument on inconsistent input (the Python layer
// validates first and gives friendlier messages).
SimResult simulate(const SimConfig& cfg);

}  // namespace rhcr
