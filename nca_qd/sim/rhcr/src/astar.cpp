#include "astar.hpp"

#include <algorithm>

namespace rhcr {
namespace {
// Direction codes (grid.hpp) in the order successors are generated: RHCR's move order
// (east, north, west, south), then the wait.
constexpr int kSuccessorOrder[5] = {1, 0, 3, 2, kWait};
}  // namespace

// States are (time, goals done, cell); the chain of waits on the start cell since time 0 is
// kept apart (slot goal_count_ + 1): under start_priority it may pass where others may not.
bool SpaceTimeAStar::seen(int t, int gi, int cell, bool at_start) {
  const size_t slot = at_start ? goal_count_ + 1 : gi;
  const size_t idx = (static_cast<size_t>(t) * (goal_count_ + 2) + slot) * grid_.cells() + cell;
  if (visited_[idx] == visit_stamp_) return true;
  visited_[idx] = static_cast<uint8_t>(visit_stamp_);
  return false;
}

void SpaceTimeAStar::push(int cell, int t, int gi, int g, int parent, bool at_start) {
  const int f = g + heuristic(cell, gi);
  nodes_.push_back({cell, t, gi, g, f, parent, at_start});
  // Smallest f first; ties prefer larger g (deeper nodes), then the newest node (RHCR's SIPP).
  open_.push(f, g, static_cast<int>(nodes_.size()) - 1);
}

bool SpaceTimeAStar::plan(const ReservationTable& rt, const AgentQuery& q, int* out_path, int& cost,
                          bool start_priority) {
  query_ = &q;
  goal_count_ = q.goals.size();
  const int Q = static_cast<int>(goal_count_);

  // suffix_[i]: cost of goal i's dwell plus all later legs and dwells (true distances).
  suffix_.assign(Q + 1, 0);
  for (int i = Q - 1; i >= 0; --i)
    suffix_[i] = q.goals[i].dwell + (i + 1 < Q ? q.dist[i + 1][q.goals[i].cell] + suffix_[i + 1] : 0);

  const size_t need = static_cast<size_t>(window_ + 1) * (Q + 2) * grid_.cells();
  if (visited_.size() < need) {
    visited_.assign(need, 0);
    visit_stamp_ = 0;
  }
  if (++visit_stamp_ == 256) {  // the epoch wrapped: really reset
    std::fill(visited_.begin(), visited_.end(), 0);
    visit_stamp_ = 1;
  }
  nodes_.clear();
  open_.clear();

  // The root never completes a goal: goals count on arrival steps (times >= 1), and a
  // dwell already in progress continues through the root's own macro below.
  seen(0, 0, q.start, true);
  push(q.start, 0, 0, 0, -1, true);

  int64_t budget = max_expansions;
  while (!open_.empty()) {
    const int id = open_.pop();
    const Node n = nodes_[id];
    ++expansions_;
    if (--budget < 0) return false;

    // Terminal 1: the window's end. Beyond it nothing is reserved, so g + h is exact.
    // Terminal 2: every goal done (not before min_end): the path ends here.
    const bool window_end = n.t >= window_;
    if (window_end || (n.gi == Q && n.t >= q.min_end)) {
      cost = n.f;
      // Reconstruct: every node fills the times after its parent with its cell (a macro
      // node covers several waits); after a path's end the agent is absent.
      for (int t = n.t; t <= window_; ++t) out_path[t] = window_end ? n.cell : kAbsent;
      out_path[std::min(n.t, window_)] = n.cell;
      for (int cur = id; nodes_[cur].parent >= 0; cur = nodes_[cur].parent) {
        const Node& child = nodes_[cur];
        const Node& par = nodes_[child.parent];
        for (int t = par.t + 1; t <= child.t; ++t) out_path[t] = child.cell;
      }
      out_path[0] = q.start;
      return true;
    }

    // Dwell macro: as in RHCR's SIPP, arriving on the current goal's cell starts its dwell at
    // once, and the dwell is the only successor (no passing through, no waiting first). The
    // dwell of an intermediate goal must fit between reservations, or the arrival is a dead
    // end; the dwell of the last goal ends the search and is not checked (SIPP returns the
    // path on arrival), so PBS sees any collision it causes as a conflict. At the root the
    // macro only continues a dwell in progress (an agent that has not arrived yet arrives
    // with its first step, like every other agent).
    const bool root = id == 0;
    if (n.gi < Q && q.goals[n.gi].cell == n.cell && q.goals[n.gi].dwell > 0 && (!root || q.start_dwell_left > 0)) {
      const int dwell = root ? q.start_dwell_left : q.goals[n.gi].dwell;
      const int t_end = std::min(n.t + dwell, window_);
      const bool last_goal = n.gi + 1 == Q;
      bool free = true;
      if (!(start_priority && n.at_start) && !last_goal)
        for (int t = n.t + 1; t <= t_end && free; ++t) free = rt.vertex_free(t, n.cell);
      if (free) {
        const int gi2 = advance(n.cell, n.gi + 1);
        // A macro that runs past the window is terminal; its g counts the whole dwell.
        if (n.t + dwell >= window_ || !seen(t_end, gi2, n.cell, n.at_start))
          push(n.cell, t_end, gi2, n.g + dwell, id, n.at_start);
      }
      continue;
    }

    // Ordinary successors: move to a 4-neighbour (in RHCR's order: east, north, west, south)
    // or wait, respecting reservations.
    const int t1 = n.t + 1;
    for (int d : kSuccessorOrder) {
      const int v = d == kWait ? n.cell : grid_.neighbor(n.cell, d);
      if (v < 0) continue;
      const bool waits_at_start = d == kWait && n.at_start;
      if (!rt.vertex_free(t1, v) && !(start_priority && waits_at_start)) continue;
      if (d != kWait && !rt.edge_free(grid_, n.t, n.cell, v)) continue;
      const int gi2 = advance(v, n.gi);
      if (seen(t1, gi2, v, waits_at_start)) continue;
      push(v, t1, gi2, n.g + 1, id, waits_at_start);
    }
  }
  return false;
}

}  // namespace rhcr
