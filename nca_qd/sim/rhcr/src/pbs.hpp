// Windowed Priority-Based Search (Ma et al., AAAI 2019) as used by RHCR (Li et al., AAAI 2021),
// decision by decision as in RHCR's public implementation (PBS + prioritize_start):
//
// * Root: every agent planned alone (in id order, each avoiding the start cells where the
//   agents planned before it still wait), then made consistent (below).
// * A node holds a priority graph (edges "lower below higher"), one windowed path per agent
//   and the list of all conflicts among its paths within the window (vertex, or swap).
// * Expansion takes the earliest conflict (a pair that has exhausted both of its children
//   before, a "nogood", is preferred) and makes two children, "a1 below a2" and "a2 below a1".
//   A child replans its new lower agent and then, until nothing is left to replan, every agent
//   of a new conflict that must give way: with prioritize_start, the one that runs into an
//   agent still waiting on its start cell; otherwise the lower one of an ordered pair.
//   Conflicts between unordered agents stay for later expansions. A child fails when an agent
//   cannot be planned or when it replans more than five times per agent it touched. The agents
//   waiting to be replanned sit in an unordered_set and the first in its iteration order goes
//   next, as in RHCR (with libstdc++, roughly the most recently added one).
// * Depth first: of two children, the one with the smaller total cost (then fewer conflicts)
//   is explored first. The search ends at the first conflict-free node.
// * Every replanned agent avoids the paths of all agents above it and, with prioritize_start,
//   the start cells of all other agents while they still wait there; it may itself keep
//   waiting on its own start cell whatever the reservations say.
//
// Failure (time limit, node budget or exhausted tree): the best node expanded (latest first
// conflict, then smaller cost) is executed with the repair of RHCR's LRA*: step by step,
// agents in a random order follow their paths, and one that would enter a cell claimed by
// another this step waits, pushing back whoever claimed its own cell. Unlike RHCR's repair
// it also refuses swaps, so every executed step stays collision-free.
#pragma once

#include <chrono>
#include <cstdint>
#include <memory>
#include <set>
#include <unordered_set>
#include <utility>
#include <vector>

#include "astar.hpp"
#include "grid.hpp"
#include "priority_order.hpp"
#include "pool_allocator.hpp"
#include "rng.hpp"

namespace rhcr {

struct PbsStats {
  int64_t nodes_expanded = 0;
  int64_t nodes_generated = 0;
};

struct PbsLimits {
  int64_t max_nodes = 0;        // high-level nodes per call; <= 0: none
  double time_limit_s = 60;     // CPU seconds per call; <= 0: none
  // A* expansions per call; <= 0: none. A bound on work, not time: the same call stops at the
  // same point on any machine and under any load (in a jammed call make_consistent's cascades
  // replan hundreds of agents per node, so nodes alone bound it loosely).
  int64_t max_expansions = 0;
  std::chrono::steady_clock::time_point deadline = std::chrono::steady_clock::time_point::max();
  bool prioritize_start = true;
};

// make_consistent's agents to replan: RHCR's std::unordered_set<int> (its iteration order
// decides who is replanned next, so the container stays the same), with its one-element
// allocations served from a free list instead of malloc.
using ReplanSet = std::unordered_set<int, std::hash<int>, std::equal_to<int>, PoolAllocator<int>>;

class WindowedPBS {
 public:
  WindowedPBS(const Grid& grid, int n_agents, int window);

  // Plans paths[agent * (window + 1) + t]. Returns true when PBS found a conflict-free
  // solution; false means the repaired best node (collision-free for `executed_steps`).
  bool solve(const std::vector<AgentQuery>& queries, int executed_steps, const PbsLimits& limits,
             Rng& rng, std::vector<int>& paths);

  const PbsStats& stats() const { return stats_; }
  int64_t low_level_expansions() const { return astar_.expansions(); }

 private:
  struct Conflict {
    int a1 = -1, a2 = -1, v1 = -1, v2 = -1, t = -1;  // v2 >= 0: swap along (v1, v2)
  };
  struct Node {
    // Per agent, its path's block in the call's arena (paths_, areas_, costs_). A child
    // shares its parent's blocks and a replanned agent gets a new one, so a copy of a node
    // copies an index per agent, not the agent's path, cost and area (with 1,400 agents those
    // copies were the planner's largest cost: docs/benchmarks.md, exact simulator).
    std::vector<int> block;
    PriorityOrder order;                      // who is above whom (priority_order.hpp)
    std::vector<Conflict> conflicts;
    std::vector<int> touched;                 // agents replanned in this node (root: all)
    int64_t total_cost = 0;
    int earliest = 1 << 30;                   // time of the chosen conflict, once expanded
  };

  // An agent's path in node n (window + 1 cells, kAbsent after its end). The pointer is good
  // until the next new_block(), which may move the arena.
  const int* path(const Node& n, int agent) const {
    return paths_.data() + static_cast<size_t>(n.block[agent]) * (window_ + 1);
  }
  // The areas an agent's path crosses (one bit per block of an 8 x 8 division of the map): two
  // paths can only meet where their areas overlap.
  uint64_t area(const Node& n, int agent) const { return areas_[n.block[agent]]; }
  // A new block at the arena's end (path, area and cost to be written): its index.
  int new_block();
  // Give `agent` in node n the path p (window + 1 cells) of estimated cost `cost`, in a new block
  // (copy on write: the blocks other nodes share stay as they are); n's total cost follows.
  // p must not point into the arena: new_block() may move it before p is copied.
  void store_path(Node& n, int agent, const int* p, int cost);
  // The node's paths as the caller's n_agents * (window + 1) array.
  void gather(const Node& n, std::vector<int>& out) const;

  bool near(int a, int b, int reach) const;
  bool conflict_between(const Node& n, int a1, int a2, Conflict& c) const;
  void conflicts_of(const Node& n, int agent, std::vector<Conflict>& out) const;
  bool waits_at_start(const int* p, int cell, int t) const;
  void add_replans(const Node& n, const std::vector<Conflict>& conflicts, ReplanSet& replan, int lower = -1,
                   int higher = -1);
  bool find_path(Node& n, int agent, const std::vector<AgentQuery>& queries, int n_planned);
  // `higher`: the agent the child's new edge put above `agent` (-1: the root, no new edge).
  bool make_consistent(Node& n, int agent, const std::vector<AgentQuery>& queries, int higher = -1);
  const Conflict& choose_conflict(Node& n) const;
  static constexpr int64_t kClockEvery = 32;
  bool out_of_time(const PbsLimits& limits, int64_t expanded, int64_t expansions0, double cpu0) const;
  void repair(const Node& best, const std::vector<AgentQuery>& queries, int executed_steps, Rng& rng,
              std::vector<int>& out);

  const Grid& grid_;
  int n_agents_, window_;
  bool prioritize_start_ = true;
  SpaceTimeAStar astar_;
  ReservationTable rt_;
  PbsStats stats_;
  std::set<std::pair<int, int>> nogood_;
  std::vector<uint64_t> row_;  // PriorityOrder::add_edge's scratch
  std::vector<int> scratch_path_;
  std::vector<char> touched_flag_;
  std::vector<char> queued_;  // mirrors make_consistent's set of agents to replan
  std::vector<int> start_;  // each agent's start cell in the current call
  // Per agent, a bit row (words_ words) of the other agents whose start cells lie within
  // 2 * window (Manhattan) of its own: the only ones its windowed path can meet (see near()).
  // Built once per call (branch-free, a row per agent), visited in increasing id; it spares
  // the conflict checks and reservations a scan over all agents.
  std::vector<uint64_t> nearby_;
  // The same within `window` (whose start cells an agent's path can reach), and the start
  // cells' rows and columns.
  std::vector<uint64_t> close_;
  int words_ = 0;
  std::vector<int> start_row_, start_col_;
  // Calls f(b) for every b < limit whose bit is set in row `a` of `bits`, in increasing b.
  template <class F>
  void for_each_agent(const std::vector<uint64_t>& bits, int a, int limit, F&& f) const {
    const uint64_t* row = bits.data() + static_cast<size_t>(a) * words_;
    for (int w = 0; w < words_ && w * 64 < limit; ++w) {
      uint64_t x = row[w];
      if (limit - w * 64 < 64) x &= (uint64_t{1} << (limit - w * 64)) - 1;
      for (; x; x &= x - 1) f(w * 64 + __builtin_ctzll(x));
    }
  }
  std::vector<uint64_t> cell_area_;  // the area bit of each cell
  uint64_t area_of(const int* p) const {
    uint64_t m = 0;
    for (int t = 0; t <= window_ && p[t] != kAbsent; ++t) m |= cell_area_[p[t]];
    return m;
  }
  void build_nearby();

  // Nodes are recycled within and across calls: a child is copied into a spent node's
  // buffers, so expanding a node allocates nothing once the pool is warm (at 200 agents the
  // copies' allocations were a tenth of the planner's time).
  static constexpr size_t kPoolBytes = size_t{32} << 20;
  std::vector<std::unique_ptr<Node>> pool_;
  // The call's path blocks: block b's path is paths_[b * (window + 1) ...], its area areas_[b],
  // its A* cost costs_[b]; block 0 is no path (all kAbsent, area 0, cost 0). Emptied at each
  // call; blocks are only appended, so every node's blocks stay valid through the call.
  std::vector<int> paths_;
  std::vector<uint64_t> areas_;
  std::vector<int> costs_;
  RowArena order_rows_;  // the nodes' priority orders' rows, likewise (priority_order.hpp)
  size_t pool_bytes_ = 0;  // what the pool's nodes hold (node_bytes)
  static size_t node_bytes(const Node& n) {
    return sizeof(Node) + (n.block.capacity() + n.touched.capacity()) * sizeof(int) +
           n.conflicts.capacity() * sizeof(Conflict) + n.order.bytes();
  }
  std::unique_ptr<Node> take_node();
  void recycle(std::unique_ptr<Node> node);
  std::vector<Conflict> fresh_;  // make_consistent's conflicts of the agent just replanned
};

}  // namespace rhcr
