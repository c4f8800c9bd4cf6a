#include "pbs.hpp"

#include <algorithm>
#include <memory>
#include <numeric>

#include "cpu_clock.hpp"

namespace rhcr {

WindowedPBS::WindowedPBS(const Grid& grid, int n_agents, int window)
    : grid_(grid),
      n_agents_(n_agents),
      window_(window),
      astar_(grid, window),
      rt_(grid.cells(), window),
      touched_flag_(n_agents, 0),
      queued_(n_agents, 0) {
  cell_area_.resize(grid.cells());
  for (int cell = 0; cell < grid.cells(); ++cell) {
    const int r = cell / grid.cols() * 8 / grid.rows(), c = cell % grid.cols() * 8 / grid.cols();
    cell_area_[cell] = uint64_t{1} << (r * 8 + c);
  }
}

// Can agents a and b come within `reach` of each other? Each moves at most `window` cells
// from its start, so pairs whose starts are farther apart never interact.
bool WindowedPBS::near(int a, int b, int reach) const {
  return std::abs(start_row_[a] - start_row_[b]) + std::abs(start_col_[a] - start_col_[b]) <= reach;
}

// RHCR's conflict test between two paths within the window: the first vertex conflict or
// swap in time order. Callers only ask about pairs of nearby_ (others never meet).
bool WindowedPBS::conflict_between(const Node& n, int a1, int a2, Conflict& c) const {
  if (!(area(n, a1) & area(n, a2))) return false;
  const int* p = path(n, a1);
  const int* q = path(n, a2);
  // Most pairs never meet: rule them out with one branch-free pass (kAbsent cells may match
  // here; the exact scan below sorts them out).
  unsigned hit = 0;
  for (int t = 0; t <= window_; ++t) hit |= static_cast<unsigned>(p[t] == q[t]);
  for (int t = 0; t < window_; ++t) hit |= static_cast<unsigned>(p[t] == q[t + 1]) & static_cast<unsigned>(q[t] == p[t + 1]);
  if (!hit) return false;
  for (int t = 0; t <= window_; ++t) {
    if (p[t] == kAbsent || q[t] == kAbsent) return false;
    if (p[t] == q[t]) {
      c = {a1, a2, p[t], -1, t};
      return true;
    }
    if (t < window_ && p[t + 1] != kAbsent && q[t + 1] != kAbsent && p[t] == q[t + 1] && q[t] == p[t + 1]) {
      c = {a1, a2, p[t], q[t], t + 1};
      return true;
    }
  }
  return false;
}

void WindowedPBS::build_nearby() {
  start_row_.resize(n_agents_);
  start_col_.resize(n_agents_);
  for (int a = 0; a < n_agents_; ++a) {
    start_row_[a] = start_[a] / grid_.cols();
    start_col_[a] = start_[a] % grid_.cols();
  }
  words_ = (n_agents_ + 63) / 64;
  nearby_.assign(static_cast<size_t>(n_agents_) * words_, 0);
  close_.assign(static_cast<size_t>(n_agents_) * words_, 0);
  const int* rows = start_row_.data();
  const int* cols = start_col_.data();
  for (int a = 0; a < n_agents_; ++a) {
    uint64_t* nb = nearby_.data() + static_cast<size_t>(a) * words_;
    uint64_t* cl = close_.data() + static_cast<size_t>(a) * words_;
    for (int w = 0; w < words_; ++w) {
      uint64_t near_bits = 0, close_bits = 0;
      const int end = std::min(64, n_agents_ - w * 64);
      for (int j = 0; j < end; ++j) {
        const int b = w * 64 + j;
        const int d = std::abs(rows[a] - rows[b]) + std::abs(cols[a] - cols[b]);
        near_bits |= static_cast<uint64_t>(d <= 2 * window_) << j;
        close_bits |= static_cast<uint64_t>(d <= window_) << j;
      }
      nb[w] = near_bits;
      cl[w] = close_bits;
    }
    const uint64_t self = ~(uint64_t{1} << (a & 63));  // an agent is not its own neighbour
    nb[a >> 6] &= self;
    cl[a >> 6] &= self;
  }
}

void WindowedPBS::conflicts_of(const Node& n, int agent, std::vector<Conflict>& out) const {
  Conflict c;
  for_each_agent(nearby_, agent, n_agents_, [&](int b) {
    if (conflict_between(n, agent, b, c)) out.push_back(c);
  });
}

// Does the path stay on `cell` from time 0 through t (and go on after t)?
bool WindowedPBS::waits_at_start(const int* p, int cell, int t) const {
  for (int s = 0; s <= t && s <= window_; ++s)
    if (p[s] != cell) return false;
  return t >= window_ || p[t + 1] != kAbsent;
}

// RHCR's choice of who gives way in each conflict (find_replan_agents).
//
// With a new edge (`lower` below `higher`, the child's one): the conflicts are its parent's,
// every one of which gave nobody under the parent's order (a node is made consistent before it
// is pushed: a conflict whose pair was ordered, or one of whose agents waited at its start,
// had one agent replanned, which removed it). Paths are the parent's, so only a pair that the
// new edge orders can give someone now: one agent at or below `lower`, the other at or above
// `higher`. The others are skipped unread (same insertions, same order, less work).
void WindowedPBS::add_replans(const Node& n, const std::vector<Conflict>& conflicts, ReplanSet& replan, int lower,
                              int higher) {
  auto low = [&](int x) { return x == lower || n.order.is_above(x, lower); };
  auto high = [&](int y) { return y == higher || n.order.is_above(higher, y); };
  for (const Conflict& c : conflicts) {
    if (queued_[c.a1] || queued_[c.a2]) continue;  // replan.count(), without hashing
    if (lower >= 0 && !((low(c.a1) && high(c.a2)) || (low(c.a2) && high(c.a1)))) continue;
    int who = -1;
    if (prioritize_start_ && waits_at_start(path(n, c.a1), c.v1, c.t)) {
      who = c.a2;
    } else if (prioritize_start_ && waits_at_start(path(n, c.a2), c.v2, c.t)) {
      who = c.a1;
    } else if (n.order.is_above(c.a1, c.a2)) {
      who = c.a1;
    } else if (n.order.is_above(c.a2, c.a1)) {
      who = c.a2;
    }
    if (who >= 0) {
      replan.insert(who);
      queued_[who] = 1;
    }
  }
}

// Plan `agent` against everyone above it and the start cells where agents [0, n_planned)
// still wait; the priority graph must be the node's.
bool WindowedPBS::find_path(Node& n, int agent, const std::vector<AgentQuery>& queries, int n_planned) {
  rt_.clear();
  n.order.for_each_above(agent, [&](int h) {
    if (h != agent && near(agent, h, 2 * window_)) rt_.add_path(grid_, path(n, h));
  });
  if (prioritize_start_)
    for_each_agent(close_, agent, n_planned, [&](int i) {
      const int* p = path(n, i);
      int leave = 1;
      while (leave <= window_ && p[leave] == p[0]) ++leave;
      rt_.add_wait(p[0], leave);
    });
  std::vector<int>& buf = scratch_path_;
  buf.assign(window_ + 1, kAbsent);
  int cost = 0;
  bool ok = astar_.plan(rt_, queries[agent], buf.data(), cost, false);
  if (!ok && prioritize_start_) ok = astar_.plan(rt_, queries[agent], buf.data(), cost, true);
  if (!ok) return false;
  store_path(n, agent, buf.data(), cost);
  if (!touched_flag_[agent]) {
    touched_flag_[agent] = 1;
    n.touched.push_back(agent);
  }
  return true;
}

// RHCR's find_consistent_paths: replan `agent` (if >= 0), then whoever must give way, until
// no ordered pair (or start waiter) conflicts; fails past five replans per touched agent.
bool WindowedPBS::make_consistent(Node& n, int agent, const std::vector<AgentQuery>& queries, int higher) {
  for (int a : n.touched) touched_flag_[a] = 1;
  // RHCR keeps the agents to replan in an unordered_set and always takes begin(): with
  // libstdc++ that is roughly the most recently added agent, not the smallest id. The same
  // container, filled and emptied in the same sequence, replans in the reference's order.
  ReplanSet replan;
  if (agent >= 0) {
    replan.insert(agent);
    queued_[agent] = 1;
  }
  add_replans(n, n.conflicts, replan, higher >= 0 ? agent : -1, higher);
  bool ok = true;
  size_t count = 0;
  std::vector<Conflict>& fresh = fresh_;
  while (!replan.empty()) {
    if (count > n.touched.size() * 5) {
      ok = false;
      break;
    }
    const int a = *replan.begin();
    replan.erase(a);
    queued_[a] = 0;
    ++count;
    if (!find_path(n, a, queries, n_agents_)) {
      ok = false;
      break;
    }
    n.conflicts.erase(std::remove_if(n.conflicts.begin(), n.conflicts.end(),
                                     [a](const Conflict& c) { return c.a1 == a || c.a2 == a; }),
                      n.conflicts.end());
    fresh.clear();
    conflicts_of(n, a, fresh);
    add_replans(n, fresh, replan);
    n.conflicts.insert(n.conflicts.end(), fresh.begin(), fresh.end());
  }
  for (int a : n.touched) touched_flag_[a] = 0;
  for (int a : replan) queued_[a] = 0;
  return ok;
}

// The earliest conflict (first of equals); a conflict of a nogood pair takes precedence.
const WindowedPBS::Conflict& WindowedPBS::choose_conflict(Node& n) const {
  const Conflict* best = &n.conflicts.front();
  for (const Conflict& c : n.conflicts)
    if (c.t < best->t) best = &c;
  n.earliest = best->t;
  if (!nogood_.empty())
    for (const Conflict& c : n.conflicts)
      if (nogood_.count({std::min(c.a1, c.a2), std::max(c.a1, c.a2)})) return c;
  return *best;
}

// The node budget is checked at every expansion; the clocks (a thread CPU clock is a system
// call, several % of a call's time when read per node) every kClockEvery expansions.
bool WindowedPBS::out_of_time(const PbsLimits& limits, int64_t expanded, int64_t expansions0, double cpu0) const {
  if (limits.max_nodes > 0 && expanded >= limits.max_nodes) return true;
  if (limits.max_expansions > 0 && astar_.expansions() - expansions0 >= limits.max_expansions) return true;
  if (expanded % kClockEvery != 0) return false;
  if (limits.time_limit_s > 0 && thread_cpu_seconds() - cpu0 > limits.time_limit_s) return true;
  return std::chrono::steady_clock::now() > limits.deadline;
}

bool WindowedPBS::solve(const std::vector<AgentQuery>& queries, int executed_steps, const PbsLimits& limits,
                        Rng& rng, std::vector<int>& out) {
  const double cpu0 = thread_cpu_seconds();
  const int64_t expansions0 = astar_.expansions();
  const int len = window_ + 1;
  prioritize_start_ = limits.prioritize_start;
  nogood_.clear();
  start_.resize(n_agents_);
  for (int a = 0; a < n_agents_; ++a) start_[a] = queries[a].start;
  build_nearby();

  // Root: every agent alone, in id order, avoiding the start cells of those planned before.
  paths_.clear();
  areas_.clear();
  costs_.clear();
  new_block();  // block 0: no path
  std::fill(paths_.begin(), paths_.end(), kAbsent);
  std::unique_ptr<Node> root = take_node();
  root->block.assign(n_agents_, 0);
  order_rows_.reset(n_agents_);
  root->order.reset(n_agents_, order_rows_);
  root->conflicts.clear();
  root->total_cost = 0;
  for (int a = 0; a < n_agents_; ++a)
    if (!find_path(*root, a, queries, a)) {  // it waits on its start cell (cost 0)
      scratch_path_.assign(len, queries[a].start);
      store_path(*root, a, scratch_path_.data(), 0);
    }
  for (int a : root->touched) touched_flag_[a] = 0;
  // Whatever the search still holds when it returns goes back to the pool.
  std::vector<std::unique_ptr<Node>> stack;
  struct Recycle {
    WindowedPBS& pbs;
    std::vector<std::unique_ptr<Node>>& nodes;
    ~Recycle() {
      for (auto& node : nodes) pbs.recycle(std::move(node));
    }
  } recycle_on_return{*this, stack};
  stack.push_back(std::move(root));
  Node& r = *stack.back();
  if (static_cast<int>(r.touched.size()) < n_agents_) {
    repair(r, queries, executed_steps, rng, out);
    return false;
  }
  Conflict c;
  for (int a = 0; a < n_agents_; ++a)
    for_each_agent(nearby_, a, n_agents_, [&](int b) {
      if (b > a && conflict_between(r, a, b, c)) r.conflicts.push_back(c);
    });
  if (!make_consistent(r, -1, queries)) {
    repair(r, queries, executed_steps, rng, out);
    return false;
  }
  if (r.conflicts.empty()) {
    gather(r, out);
    return true;
  }

  const int64_t min_cost = r.total_cost;
  Node best;  // best expanded node: latest first conflict, then smaller cost
  bool have_best = false;
  int64_t expanded = 0;
  while (!stack.empty()) {
    if (out_of_time(limits, expanded, expansions0, cpu0)) {
      if (!have_best) std::swap(best, *stack.back());  // nothing expanded yet: the root
      break;
    }
    std::unique_ptr<Node> node = std::move(stack.back());
    stack.pop_back();
    if (node->conflicts.empty()) {
      gather(*node, out);
      recycle(std::move(node));
      return true;
    }
    const Conflict conflict = choose_conflict(*node);
    ++expanded;
    ++stats_.nodes_expanded;

    // The best expanded node so far (latest first conflict, then smaller cost) keeps what a
    // failed call's repair needs of it: its paths (and the two figures it is ranked by). The
    // node itself is spent once its two children exist: the first gets a copy of it, the
    // second its buffers.
    if (!have_best || node->earliest > best.earliest ||
        (node->earliest == best.earliest && node->total_cost < best.total_cost)) {
      best.block = node->block;
      best.earliest = node->earliest;
      best.total_cost = node->total_cost;
      have_best = true;
    }
    Node& parent = *node;
    std::unique_ptr<Node> children[2];
    for (int k = 0; k < 2; ++k) {
      const int lower = k == 0 ? conflict.a1 : conflict.a2;
      const int higher = k == 0 ? conflict.a2 : conflict.a1;
      std::unique_ptr<Node> child = take_node();
      if (k == 1) {
        std::swap(child->block, parent.block);
        std::swap(child->conflicts, parent.conflicts);
        std::swap(child->order, parent.order);
      } else {
        child->block = parent.block;
        child->conflicts = parent.conflicts;
        child->order.copy_from(parent.order);
      }
      child->order.add_edge(lower, higher, row_);
      child->total_cost = parent.total_cost;
      if (!make_consistent(*child, lower, queries, higher)) {
        recycle(std::move(child));
        continue;
      }
      ++stats_.nodes_generated;
      if (child->total_cost == min_cost && child->conflicts.empty()) {
        gather(*child, out);
        recycle(std::move(child));
        recycle(std::move(children[0]));
        recycle(std::move(node));
        return true;
      }
      children[k] = std::move(child);
    }
    recycle(std::move(node));
    if (children[0] && children[1]) {
      const bool first_better =
          children[0]->total_cost < children[1]->total_cost ||
          (children[0]->total_cost == children[1]->total_cost &&
           children[0]->conflicts.size() < children[1]->conflicts.size());
      if (first_better) std::swap(children[0], children[1]);  // the better one on top
      stack.push_back(std::move(children[0]));
      stack.push_back(std::move(children[1]));
    } else if (children[0] || children[1]) {
      stack.push_back(std::move(children[0] ? children[0] : children[1]));
    } else {
      nogood_.insert({std::min(conflict.a1, conflict.a2), std::max(conflict.a1, conflict.a2)});
    }
  }
  repair(best, queries, executed_steps, rng, out);
  return false;
}

std::unique_ptr<WindowedPBS::Node> WindowedPBS::take_node() {
  if (pool_.empty()) return std::make_unique<Node>();
  std::unique_ptr<Node> node = std::move(pool_.back());
  pool_.pop_back();
  pool_bytes_ -= node_bytes(*node);
  node->touched.clear();
  node->total_cost = 0;
  node->earliest = 1 << 30;
  return node;
}

int WindowedPBS::new_block() {
  const int b = static_cast<int>(costs_.size());
  paths_.resize(paths_.size() + window_ + 1);
  areas_.push_back(0);
  costs_.push_back(0);
  return b;
}

void WindowedPBS::store_path(Node& n, int agent, const int* p, int cost) {
  const int b = new_block();
  std::copy(p, p + window_ + 1, paths_.begin() + static_cast<ptrdiff_t>(b) * (window_ + 1));
  areas_[b] = area_of(p);
  costs_[b] = cost;
  n.total_cost += cost - costs_[n.block[agent]];
  n.block[agent] = b;
}

void WindowedPBS::gather(const Node& n, std::vector<int>& out) const {
  const int len = window_ + 1;
  out.resize(static_cast<size_t>(n_agents_) * len);
  for (int a = 0; a < n_agents_; ++a)
    std::copy(path(n, a), path(n, a) + len, out.begin() + static_cast<ptrdiff_t>(a) * len);
}

void WindowedPBS::recycle(std::unique_ptr<Node> node) {
  // The depth-first stack holds hundreds of nodes when a call ends, and the next call needs as
  // many again: keep spare nodes up to kPoolBytes of what they hold.
  if (!node) return;
  const size_t bytes = node_bytes(*node);
  if (pool_bytes_ + bytes > kPoolBytes) return;
  pool_bytes_ += bytes;
  pool_.push_back(std::move(node));
}

// RHCR's LRA* repair of a failed call, plus a swap check: execute `executed_steps` steps of
// the node's paths, agents in a random order each step; an agent whose next cell is claimed
// waits, and an agent that waits pushes back whoever claimed its cell.
void WindowedPBS::repair(const Node& n, const std::vector<AgentQuery>& queries, int executed_steps, Rng& rng,
                         std::vector<int>& out) {
  const int len = window_ + 1, N = n_agents_, cells = grid_.cells();
  out.assign(static_cast<size_t>(N) * len, 0);
  std::vector<int> last(N), ptr(N, 1), order(N);
  for (int a = 0; a < N; ++a) {
    const int* p = n.block.empty() ? nullptr : path(n, a);
    int l = 0;
    while (p && l + 1 < len && p[l + 1] != kAbsent) ++l;
    last[a] = p ? l : 0;
    out[a * len] = queries[a].start;
  }
  auto cell_of = [&](int a, int s) {
    const int* p = n.block.empty() ? nullptr : path(n, a);
    return p ? p[std::min(s, last[a])] : queries[a].start;
  };
  std::vector<int> claim(cells, -1), before(cells, -1);
  std::vector<char> decided(N, 0);
  // Wait at the previous cell; whoever claimed that cell waits too (and gives back its step).
  auto wait = [&](auto&& self, int a, int t) -> void {
    const int cell = out[a * len + t - 1];
    out[a * len + t] = cell;
    const int other = claim[cell];
    claim[cell] = a;
    if (other >= 0 && other != a) {
      self(self, other, t);
      --ptr[other];
    }
  };
  for (int t = 1; t <= executed_steps; ++t) {
    for (int a = 0; a < N; ++a) before[out[a * len + t - 1]] = a;
    std::iota(order.begin(), order.end(), 0);
    for (int i = N - 1; i > 0; --i) std::swap(order[i], order[rng.below(i + 1)]);
    std::fill(decided.begin(), decided.end(), 0);
    for (int a : order) {
      ptr[a] = std::min(ptr[a], last[a]);
      const int next = cell_of(a, ptr[a]);
      const int cur = out[a * len + t - 1];
      decided[a] = 1;
      if (next == cur) {
        out[a * len + t] = cur;
        ++ptr[a];
        const int other = claim[cur];
        claim[cur] = a;
        if (other >= 0 && other != a) {
          wait(wait, other, t);
          --ptr[other];
          claim[cur] = a;
        }
        continue;
      }
      const int b = before[next];
      const bool swap = b >= 0 && b != a && decided[b] && out[b * len + t] == cur;
      if (swap || claim[next] >= 0) {
        wait(wait, a, t);
      } else {
        out[a * len + t] = next;
        ++ptr[a];
        claim[next] = a;
      }
    }
    for (int a = 0; a < N; ++a) {
      claim[out[a * len + t]] = -1;
      before[out[a * len + t - 1]] = -1;
    }
  }
  for (int a = 0; a < N; ++a)
    for (int s = executed_steps + 1; s < len; ++s) out[a * len + s] = out[a * len + executed_steps];
}

}  // namespace rhcr
