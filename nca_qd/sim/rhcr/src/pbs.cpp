#include "pbs.hpp"

#include <algorithm>
#include <memory>

namespace rhcr {

WindowedPBS::WindowedPBS(const Grid& grid, int n_agents, int window)
    : grid_(grid),
      n_agents_(n_agents),
      window_(window),
      astar_(grid, window),
      rt_(grid.cells(), window),
      up_(n_agents),
      down_(n_agents),
      mark_(n_agents, 0),
      in_set_(n_agents, 0),
      indeg_(n_agents, 0),
      occ_stamp_((window + 1) * grid.cells(), 0),
      occ_agent_((window + 1) * grid.cells(), -1) {}

void WindowedPBS::build_adjacency(const Node& n) {
  for (int a : touched_) {
    up_[a].clear();
    down_[a].clear();
  }
  touched_.clear();
  for (const auto& [hi, lo] : n.edges) push_edge(hi, lo);
}

// A child's graph is its parent's plus one edge: solve() adds it before and removes it
// after processing the child, instead of rebuilding every list from the child's edges.
void WindowedPBS::push_edge(int hi, int lo) {
  if (up_[lo].empty() && down_[lo].empty()) touched_.push_back(lo);
  if (up_[hi].empty() && down_[hi].empty()) touched_.push_back(hi);
  up_[lo].push_back(hi);
  down_[hi].push_back(lo);
}

void WindowedPBS::pop_edge(int hi, int lo) {
  up_[lo].pop_back();
  down_[hi].pop_back();
}

// All agents above (upward) or below `agent` in the current priority graph, excluding it.
void WindowedPBS::collect(int agent, bool upward, std::vector<int>& out) {
  out.clear();
  if (++mark_stamp_ == 0) {
    std::fill(mark_.begin(), mark_.end(), 0);
    mark_stamp_ = 1;
  }
  mark_[agent] = mark_stamp_;
  std::vector<int>& stack = stack_;
  stack.assign(1, agent);
  while (!stack.empty()) {
    const int u = stack.back();
    stack.pop_back();
    for (int v : (upward ? up_[u] : down_[u]))
      if (mark_[v] != mark_stamp_) {
        mark_[v] = mark_stamp_;
        out.push_back(v);
        stack.push_back(v);
      }
  }
}

bool WindowedPBS::paths_conflict(const int* p, const int* q, int horizon) const {
  for (int t = 1; t <= horizon; ++t) {
    if (p[t] == q[t]) return true;
    if (p[t] == q[t - 1] && p[t - 1] == q[t]) return true;
  }
  return false;
}

// Earliest vertex or swap conflict among all agents within times 1..horizon.
WindowedPBS::Conflict WindowedPBS::find_conflict(const Node& n, int horizon) {
  const int cells = grid_.cells();
  if (++occ_current_ == 0) {
    std::fill(occ_stamp_.begin(), occ_stamp_.end(), 0);
    occ_current_ = 1;
  }
  for (int a = 0; a < n_agents_; ++a) {
    const int idx = path(n, a)[0];
    occ_stamp_[idx] = occ_current_;
    occ_agent_[idx] = a;
  }
  for (int t = 1; t <= horizon; ++t) {
    for (int a = 0; a < n_agents_; ++a) {
      const int* p = path(n, a);
      const int idx = t * cells + p[t];
      if (occ_stamp_[idx] == occ_current_) return {occ_agent_[idx], a, t};  // vertex conflict
      occ_stamp_[idx] = occ_current_;
      occ_agent_[idx] = a;
    }
    for (int a = 0; a < n_agents_; ++a) {
      const int* p = path(n, a);
      if (p[t] == p[t - 1]) continue;
      const int prev = (t - 1) * cells + p[t];  // who stood at my destination a step before?
      if (occ_stamp_[prev] != occ_current_) continue;
      const int b = occ_agent_[prev];
      if (b != a && path(n, b)[t] == p[t - 1]) return {std::min(a, b), std::max(a, b), t};  // swap
    }
  }
  return {};
}

// Replan one agent against the paths of every agent above it (priority graph must be built).
bool WindowedPBS::replan(Node& n, int agent, const std::vector<AgentQuery>& queries) {
  std::vector<int>& above = replan_above_;
  collect(agent, true, above);
  rt_.clear();
  for (int a : above) rt_.add_path(grid_, path(n, a));
  int cost = 0;
  if (!astar_.plan(rt_, queries[agent], path(n, agent), cost)) return false;
  n.total_cost += cost - n.cost[agent];
  n.cost[agent] = cost;
  return true;
}

// PBS's UpdatePlan: replan `lower` and then, in topological order, each agent below it that
// collides with an agent above it (the priority graph must be the child's).
bool WindowedPBS::update_child(Node& child, int lower, const std::vector<AgentQuery>& queries) {
  // Scratch kept between calls (no allocation per child); in_set_ and indeg_ are all zero
  // outside this function.
  std::vector<int>& below = below_;
  collect(lower, false, below);
  below.push_back(lower);
  // Topological order of {lower} ∪ below, restricted to that set (Kahn's algorithm).
  std::vector<int>&in_set = in_set_, &indeg = indeg_, &order = order_, &ready = ready_;
  order.clear();
  ready.clear();
  for (int a : below) in_set[a] = 1;
  for (int a : below)
    for (int hi : up_[a])
      if (in_set[hi]) ++indeg[a];
  for (int a : below)
    if (indeg[a] == 0) ready.push_back(a);
  while (!ready.empty()) {
    std::sort(ready.begin(), ready.end(), std::greater<>());
    const int a = ready.back();
    ready.pop_back();
    order.push_back(a);
    for (int lo : down_[a])
      if (in_set[lo] && --indeg[lo] == 0) ready.push_back(lo);
  }
  for (int a : below) in_set[a] = indeg[a] = 0;
  std::vector<int>& above = child_above_;
  for (int a : order) {
    bool needs = a == lower;
    if (!needs) {
      collect(a, true, above);
      for (int hi : above)
        if (paths_conflict(path(child, a), path(child, hi), window_)) {
          needs = true;
          break;
        }
    }
    if (needs && !replan(child, a, queries)) return false;
  }
  return true;
}

bool WindowedPBS::solve(const std::vector<AgentQuery>& queries, int executed_steps, int64_t max_nodes,
                        std::chrono::steady_clock::time_point deadline, std::vector<int>& out) {
  const int len = window_ + 1;
  // Root: every agent planned alone.
  auto root = std::make_unique<Node>();
  root->paths.assign(n_agents_ * len, 0);
  root->cost.assign(n_agents_, 0);
  rt_.clear();
  bool root_ok = true;
  for (int a = 0; a < n_agents_ && root_ok; ++a) {
    int cost = 0;
    root_ok = astar_.plan(rt_, queries[a], path(*root, a), cost);
    root->cost[a] = cost;
    root->total_cost += cost;
  }
  if (!root_ok) {
    fallback(Node{root->paths, root->cost, {}, 0}, queries, executed_steps, out);
    return false;
  }

  std::vector<std::unique_ptr<Node>> stack;
  stack.push_back(std::move(root));
  Node last;  // last expanded node, the fallback's priority order
  int64_t expanded = 0;
  while (!stack.empty()) {
    std::unique_ptr<Node> node = std::move(stack.back());
    stack.pop_back();
    const Conflict c = find_conflict(*node, window_);
    if (c.a < 0) {
      out = std::move(node->paths);
      return true;
    }
    if (expanded >= max_nodes || std::chrono::steady_clock::now() > deadline) {
      stack.clear();
      last = std::move(*node);
      break;
    }
    ++expanded;
    ++stats_.nodes_expanded;

    std::unique_ptr<Node> children[2];
    build_adjacency(*node);
    for (int k = 0; k < 2; ++k) {
      const int hi = k == 0 ? c.a : c.b;
      const int lo = k == 0 ? c.b : c.a;
      // The new pair must not contradict the existing order (lo already above hi).
      std::vector<int> above_hi;
      collect(hi, true, above_hi);
      if (std::find(above_hi.begin(), above_hi.end(), lo) != above_hi.end()) continue;
      auto child = std::make_unique<Node>(*node);
      child->edges.emplace_back(hi, lo);
      ++stats_.nodes_generated;
      push_edge(hi, lo);
      if (update_child(*child, lo, queries)) children[k] = std::move(child);
      pop_edge(hi, lo);
    }
    // Depth first, cheaper child on top of the stack.
    if (children[0] && children[1] && children[0]->total_cost < children[1]->total_cost)
      std::swap(children[0], children[1]);
    for (auto& ch : children)
      if (ch) stack.push_back(std::move(ch));
    if (stack.empty()) last = std::move(*node);
  }
  fallback(last, queries, executed_steps, out);
  return false;
}

void WindowedPBS::fallback(const Node& n, const std::vector<AgentQuery>& queries, int executed_steps,
                           std::vector<int>& out) {
  const int len = window_ + 1;
  // Total order: Kahn's algorithm on the node's partial order, smallest agent id first.
  build_adjacency(n);
  std::vector<int> indeg(n_agents_, 0), order;
  for (int a = 0; a < n_agents_; ++a) indeg[a] = static_cast<int>(up_[a].size());
  std::vector<int> ready;
  for (int a = n_agents_ - 1; a >= 0; --a)
    if (indeg[a] == 0) ready.push_back(a);
  while (!ready.empty()) {
    std::sort(ready.begin(), ready.end(), std::greater<>());
    const int a = ready.back();
    ready.pop_back();
    order.push_back(a);
    for (int lo : down_[a])
      if (--indeg[lo] == 0) ready.push_back(lo);
  }
  std::vector<int> rank(n_agents_);
  for (int i = 0; i < n_agents_; ++i) rank[order[i]] = i;

  // Prioritized planning; an agent that cannot be planned waits in place.
  out.assign(n_agents_ * len, 0);
  std::vector<char> waiting(n_agents_, 0);
  rt_.clear();
  for (int a : order) {
    int cost = 0;
    int* p = out.data() + a * len;
    if (!astar_.plan(rt_, queries[a], p, cost)) {
      std::fill(p, p + len, queries[a].start);
      waiting[a] = 1;
    }
    rt_.add_path(grid_, p);
  }
  // Repair: a waiter may block someone planned earlier. Turn the lower-ranked mover of each
  // remaining conflict (within the executed steps) into a waiter until none is left.
  Node view;
  view.paths = std::move(out);
  for (;;) {
    const Conflict c = find_conflict(view, executed_steps);
    if (c.a < 0) break;
    int victim;
    if (waiting[c.a]) victim = c.b;
    else if (waiting[c.b]) victim = c.a;
    else victim = rank[c.a] > rank[c.b] ? c.a : c.b;
    if (waiting[victim]) break;  // two waiters cannot collide (distinct start cells)
    int* p = path(view, victim);
    std::fill(p, p + len, queries[victim].start);
    waiting[victim] = 1;
  }
  out = std::move(view.paths);
}

}  // namespace rhcr
