// Single-agent planner of windowed PBS: space-time A* on a reservation table.
//
// An agent plans from its current cell through its queue of goals. Only the first `window`
// timesteps are constrained (conflicts beyond the window are ignored, as in RHCR), so a
// state at time `window` is terminal and its remaining cost is exactly the heuristic: the
// sum of true (BFS) distances along the goal queue plus the dwell times still owed.
//
// Goal semantics (shared with the executor in rhcr.cpp):
//   * a goal with dwell 0 is done the moment the agent stands on its cell;
//   * a goal with dwell d > 0 is done after the agent arrives and then stays d more
//     timesteps without leaving. A* models this with a "dwell macro" successor (d waits in
//     one edge). As in RHCR's SIPP, arriving on the goal starts the dwell (the macro is the
//     arrival's only successor); an intermediate goal's dwell must fit between reservations,
//     the last goal's dwell is not checked (PBS then sees any collision as a conflict).
// Like RHCR's SIPP, a path ends when the agent has done its whole queue (times after that
// hold kAbsent: the agent reserves nothing there and conflicts with nobody); a path may not
// end before `min_end`, so every executed step has a cell.
//
// Tie-breaking, as RHCR's SIPP: among states of equal f, the larger g; among equal f and g,
// the newest (its Fibonacci heap puts a pushed node on top of its equals), with moves
// generated east, north, west, south. Among equally short routes an agent thus keeps to the
// last of these directions that still leads closer. This is not cosmetic: which of the many
// shortest routes agents take decides how often they meet. From the reference's own planning
// inputs (paper 33x36 layout, 340 agents) these rules give the reference's root paths agent
// for agent; breaking ties the other way gave 10 % more root conflicts.
//
// prioritize_start (RHCR's option, on in the paper): an agent that has not left its start
// cell may keep waiting there whatever the reservations say (`start_priority`); PBS then
// replans whoever runs into it.
#pragma once

#include <algorithm>
#include <cstdint>
#include <vector>

#include "grid.hpp"

namespace rhcr {

struct Goal {
  int cell;
  int dwell;
};

// A path cell after the path's end.
constexpr int kAbsent = -1;

// Cells occupied by higher-priority agents at times 0..window, for vertex and swap checks.
// One 16-bit slot per (time, cell): the table's epoch in the high byte (a slot of an older
// epoch is empty) and the directions the reserving agents came from in the low byte. Small
// (2 bytes a slot: 26 KB at 33x36 with w = 10) because it is rebuilt for every single-agent
// plan and read at every A* successor.
class ReservationTable {
 public:
  ReservationTable(int cells, int window) : cells_(cells), window_(window), slot_((window + 1) * cells, 0) {}

  void clear() {
    if (++current_ == 256) {  // the epoch wrapped: really reset
      std::fill(slot_.begin(), slot_.end(), 0);
      current_ = 1;
    }
  }

  // Reserve an agent's path (window + 1 cells, times 0..window; kAbsent cells reserve nothing).
  void add_path(const Grid& grid, const int* path) {
    for (int t = 0; t <= window_ && path[t] != kAbsent; ++t) {
      uint16_t& s = slot_[t * cells_ + path[t]];
      if ((s >> 8) != current_) s = static_cast<uint16_t>(current_ << 8);
      if (t > 0 && path[t] != path[t - 1]) s |= static_cast<uint16_t>(1u << grid.direction(path[t], path[t - 1]));
    }
  }

  // Reserve `cell` at times [0, t_end) (t_end clipped to the window): another agent waiting on
  // its start cell (RHCR's prioritize_start).
  void add_wait(int cell, int t_end) {
    for (int t = 0; t < t_end && t <= window_; ++t) {
      uint16_t& s = slot_[t * cells_ + cell];
      if ((s >> 8) != current_) s = static_cast<uint16_t>(current_ << 8);
    }
  }

  bool vertex_free(int t, int cell) const { return (slot_[t * cells_ + cell] >> 8) != current_; }

  // May an agent move from u (time t) to v (time t+1)? Not if someone at u at t+1 came from v.
  bool edge_free(const Grid& grid, int t, int u, int v) const {
    const uint16_t s = slot_[(t + 1) * cells_ + u];
    return (s >> 8) != current_ || !(s & (1u << grid.direction(u, v)));
  }

 private:
  int cells_, window_;
  std::vector<uint16_t> slot_;
  unsigned current_ = 1;  // 1..255
};

// What one agent must plan: start cell, remaining dwell if it is mid-dwell on goals[0]
// (0 otherwise), and its goal queue with a distance table per goal.
struct AgentQuery {
  int start = 0;
  int start_dwell_left = 0;
  int min_end = 0;  // the path may not end (all goals done) before this time
  std::vector<Goal> goals;
  std::vector<const uint16_t*> dist;
};

// A* open list as buckets: pops the smallest f, among equal f the largest g, among equal f
// and g the newest node (the order of RHCR's SIPP; a binary heap on (f, -g, -id) pops the
// same node). f and g are small non-negative integers, so a bucket per (f, g) holding a
// stack of node ids replaces the heap's O(log n) sifts with O(1) pushes and pops.
class BucketOpenList {
 public:
  bool empty() const { return size_ == 0; }
  void push(int f, int g, int id) {
    if (f >= static_cast<int>(rows_.size())) rows_.resize(f + 1);
    Row& row = rows_[f];
    if (g >= static_cast<int>(row.stacks.size())) row.stacks.resize(g + 1);
    if (!row.used) {
      row.used = true;
      used_.push_back(f);
    }
    row.stacks[g].push_back(id);
    ++row.count;
    row.top_g = std::max(row.top_g, g);
    min_f_ = std::min(min_f_, f);
    ++size_;
  }
  int pop() {
    while (rows_[min_f_].count == 0) ++min_f_;
    Row& row = rows_[min_f_];
    while (row.stacks[row.top_g].empty()) --row.top_g;
    std::vector<int>& stack = row.stacks[row.top_g];
    const int id = stack.back();
    stack.pop_back();
    if (--row.count == 0) row.top_g = -1;
    --size_;
    return id;
  }
  void clear() {
    for (int f : used_) {
      Row& row = rows_[f];
      for (auto& stack : row.stacks) stack.clear();
      row.count = 0;
      row.top_g = -1;
      row.used = false;
    }
    used_.clear();
    size_ = 0;
    min_f_ = 1 << 30;
  }

 private:
  struct Row {
    std::vector<std::vector<int>> stacks;  // by g
    int count = 0;
    int top_g = -1;  // no non-empty stack above it
    bool used = false;
  };
  std::vector<Row> rows_;
  std::vector<int> used_;
  int64_t size_ = 0;
  int min_f_ = 1 << 30;
};

class SpaceTimeAStar {
 public:
  SpaceTimeAStar(const Grid& grid, int window) : grid_(grid), window_(window) {}

  // Plans into out_path[0..window]; returns false if no path exists (or the expansion
  // budget is exhausted). `cost` is the path's estimated total cost g + h at its end.
  // With `start_priority`, waiting on the start cell (before first leaving it) ignores the
  // reservations of that cell.
  bool plan(const ReservationTable& rt, const AgentQuery& q, int* out_path, int& cost,
            bool start_priority = false);

  int64_t expansions() const { return expansions_; }
  int max_expansions = 200000;

 private:
  struct Node {
    int cell;
    int t;   // time of the state, capped at window
    int gi;  // number of goals already done
    int g;   // cost so far (time, plus dwell beyond the window for an overflowing macro)
    int f;
    int parent;
    bool at_start;  // has waited on the start cell since time 0
  };

  int heuristic(int cell, int gi) const {
    if (gi >= static_cast<int>(goal_count_)) return 0;
    return query_->dist[gi][cell] + suffix_[gi];
  }
  // Goals with dwell 0 are done on arrival: skip every such goal at this cell.
  int advance(int cell, int gi) const {
    while (gi < static_cast<int>(goal_count_) && query_->goals[gi].cell == cell && query_->goals[gi].dwell == 0) ++gi;
    return gi;
  }
  bool seen(int t, int gi, int cell, bool at_start);
  void push(int cell, int t, int gi, int g, int parent, bool at_start);

  const Grid& grid_;
  int window_;
  const AgentQuery* query_ = nullptr;
  size_t goal_count_ = 0;
  std::vector<int> suffix_;
  std::vector<Node> nodes_;
  BucketOpenList open_;
  // Visited states: the plan's epoch per (time, goals done, cell); one byte a state, so that
  // the table stays in cache (a plan reads it at every successor).
  std::vector<uint8_t> visited_;
  unsigned visit_stamp_ = 0;  // 1..255 while planning
  int64_t expansions_ = 0;
};

}  // namespace rhcr
