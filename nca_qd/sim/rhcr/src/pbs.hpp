// Windowed Priority-Based Search (Ma et al., AAAI 2019) as used by RHCR (Li et al., AAAI 2021).
//
// High level: a depth-first search over priority orderings. A node holds a partial order
// (edges "hi before lo") and one windowed path per agent, each planned by space-time A*
// against the paths of all agents above it. Expanding a node picks the earliest conflict
// (a_i, a_j) and creates two children, "a_i before a_j" and "a_j before a_i"; a child
// replans the lower agent and, in topological order, every agent below it whose path now
// collides with someone above it. A child whose replanning fails is pruned; the cheaper
// child is explored first. The search ends at the first conflict-free node, or fails when
// the tree is exhausted, the node budget is spent or the deadline passes.
//
// Fallback on failure (documented contract: every executed step stays collision-free):
// prioritized planning in the order of the last expanded node (its partial order extended
// by agent id), where an agent that cannot be planned waits in place; then, while two
// agents still collide within the executed steps, the lower one of them that moves is
// turned into a waiter. Waiters never collide with each other (start cells are distinct),
// so this terminates with a collision-free plan for the executed steps.
#pragma once

#include <chrono>
#include <cstdint>
#include <utility>
#include <vector>

#include "astar.hpp"
#include "grid.hpp"

namespace rhcr {

struct PbsStats {
  int64_t nodes_expanded = 0;
  int64_t nodes_generated = 0;
};

class WindowedPBS {
 public:
  WindowedPBS(const Grid& grid, int n_agents, int window);

  // Plans paths[agent * (window + 1) + t]. Returns true when PBS found a conflict-free
  // solution; false means the fallback plan was produced (collision-free for the first
  // `executed_steps` steps).
  bool solve(const std::vector<AgentQuery>& queries, int executed_steps, int64_t max_nodes,
             std::chrono::steady_clock::time_point deadline, std::vector<int>& paths);

  const PbsStats& stats() const { return stats_; }
  int64_t low_level_expansions() const { return astar_.expansions(); }

 private:
  struct Node {
    std::vector<int> paths;                   // n_agents * (window + 1)
    std::vector<int> cost;                    // per agent, from A*
    std::vector<std::pair<int, int>> edges;   // (higher, lower) priority pairs
    int64_t total_cost = 0;
  };
  struct Conflict {
    int a = -1, b = -1, t = -1;
  };

  const int* path(const Node& n, int agent) const { return n.paths.data() + agent * (window_ + 1); }
  int* path(Node& n, int agent) { return n.paths.data() + agent * (window_ + 1); }

  void build_adjacency(const Node& n);
  void push_edge(int hi, int lo);
  void pop_edge(int hi, int lo);
  void collect(int agent, bool upward, std::vector<int>& out);  // ancestors or descendants
  bool paths_conflict(const int* p, const int* q, int horizon) const;
  Conflict find_conflict(const Node& n, int horizon);
  bool replan(Node& n, int agent, const std::vector<AgentQuery>& queries);
  bool update_child(Node& child, int lower, const std::vector<AgentQuery>& queries);
  void fallback(const Node& n, const std::vector<AgentQuery>& queries, int executed_steps,
                std::vector<int>& paths);

  const Grid& grid_;
  int n_agents_, window_;
  SpaceTimeAStar astar_;
  ReservationTable rt_;
  PbsStats stats_;
  // Scratch: priority graph of the node being processed, and stamped marks.
  std::vector<std::vector<int>> up_, down_;
  std::vector<int> touched_;
  std::vector<uint32_t> mark_;
  std::vector<int> in_set_, indeg_;  // update_child: all zero between calls
  std::vector<int> stack_, below_, order_, ready_, child_above_, replan_above_;  // scratch
  uint32_t mark_stamp_ = 0;
  std::vector<uint32_t> occ_stamp_;
  std::vector<int> occ_agent_;
  uint32_t occ_current_ = 0;
};

}  // namespace rhcr
