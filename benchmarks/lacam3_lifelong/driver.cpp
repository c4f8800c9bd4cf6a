// Lifelong driver around the PIBT with swap of Kei18/lacam3 (its class PIBT, set_new_config with
// flg_swap = true), for benchmarks/check_pibt_swap_reference.py: it runs lacam3's planner, one
// step per call, under nca-qd's task model, so that nca-qd's `planner="pibt_swap"` can be set
// side by side with the planner it re-implements. Our code: it is compiled against a lacam3
// checkout given at build time (its headers and sources, included, never copied here).
//
// Task model, as nca-qd's simulate_pibt (nca_qd/sim/rhcr/src/pibt.cpp, tasks.hpp):
//   * start cells: a partial Fisher-Yates over the traversable cells (row-major), run's stream;
//   * goals: each agent cycles through the scenario's goal classes, a class's cell drawn by its
//     weights from the run's stream;
//   * priority: timesteps since the goal was assigned, then a per-agent tie-breaker drawn once
//     from the planner's stream (seed ^ 0x5DEECE66D), then the agent's index;
//   * an agent on its goal dwells there `dwell` steps (pinned: its next cell preset);
//   * RHCR's congestion rule, checked at the end of every round of `replan` steps.
// The streams (xoshiro256** seeded through splitmix64, Lemire's bounded integers) are written
// again here, so that a seed gives the same starts, goals and agent tie-breakers as nca-qd.
//
// Lifelong goals in lacam3's one-shot classes: one Instance and one DistTable for all agents;
// on a new goal g of agent a, the instance's goal a becomes g and the table's row a becomes g's
// distances (computed once per cell by lacam3's DistTable on a one-agent instance, cached). The
// planner reads both through its pointers, so it always sees the current goals.
//
// --ties lacam  : lacam3's own tie-breaking (one random float per neighbour), unchanged;
// --ties replay : (hooked build, see hook_pibt.cpp) the candidate order of nca-qd's push(): its
//                 neighbour order, its Fisher-Yates with the planner's stream, a stable sort by
//                 distance only; with it, any difference in the agents' paths is one of the
//                 PIBT-with-swap logic itself.
// The graph is always lacam3's own (its map loader; neighbours left, right, row+1, row-1).
// Output: one line of key=value figures on stdout; with --trace, each step's cells (int32,
// N per step, from the start configuration on) to a binary file.
#include <algorithm>
#include <cstdint>
#include <cstdio>
#include <ctime>
#include <fstream>
#include <iostream>
#include <numeric>
#include <stdexcept>
#include <string>
#include <vector>

#include "dist_table.hpp"
#include "graph.hpp"
#include "instance.hpp"
#include "pibt.hpp"

#include "../../nca_qd/sim/rhcr/src/rng.hpp"  // found relative to this file, not in lacam3

namespace {

// The core's own random stream (the driver must draw what the core draws, seed for seed).
using Stream = rhcr::Rng;

// The scenario file written by check_pibt_swap_reference.py: "rows cols", the mask (one row a
// line, 1 = traversable), the classes ("dwell k", then k lines "cell weight"), the cycle.
struct GoalClass {
  int dwell = 0;
  std::vector<int> cells;
  std::vector<double> cum;  // running sums of the weights
};
struct Scenario {
  int rows = 0, cols = 0;
  std::vector<char> trav;
  std::vector<GoalClass> classes;
  std::vector<int> cycle;
};

Scenario read_scenario(const std::string& path) {
  std::ifstream in(path);
  if (!in) throw std::runtime_error("cannot open " + path);
  Scenario sc;
  in >> sc.rows >> sc.cols;
  sc.trav.assign(sc.rows * sc.cols, 0);
  for (int r = 0; r < sc.rows; ++r) {
    std::string line;
    in >> line;
    if (static_cast<int>(line.size()) != sc.cols) throw std::runtime_error("bad mask row in " + path);
    for (int c = 0; c < sc.cols; ++c) sc.trav[r * sc.cols + c] = line[c] == '1';
  }
  int n_classes = 0;
  in >> n_classes;
  sc.classes.resize(n_classes);
  for (auto& cls : sc.classes) {
    int k = 0;
    double run = 0;
    in >> cls.dwell >> k;
    for (int x = 0; x < k; ++x) {
      int cell = 0;
      double weight = 0;
      in >> cell >> weight;
      cls.cells.push_back(cell);
      cls.cum.push_back(run += weight);
    }
  }
  int len = 0;
  in >> len;
  sc.cycle.resize(len);
  for (auto& id : sc.cycle) in >> id;
  if (!in || sc.cycle.empty()) throw std::runtime_error("truncated scenario " + path);
  return sc;
}

struct Task {
  int cell = 0, dwell = 0;
};

Task draw_task(const Scenario& sc, Stream& rng, int& phase) {
  const GoalClass& cls = sc.classes[sc.cycle[phase]];
  phase = (phase + 1) % static_cast<int>(sc.cycle.size());
  const double u = rng.uniform() * cls.cum.back();
  size_t at = std::upper_bound(cls.cum.begin(), cls.cum.end(), u) - cls.cum.begin();
  if (at >= cls.cum.size()) at = cls.cum.size() - 1;
  return {cls.cells[at], cls.dwell};
}

// nca-qd's neighbour order (its Grid): row-1, column+1, row+1, column-1; -1 if blocked or off.
int our_neighbor(const Scenario& sc, int cell, int d) {
  static const int dr[4] = {-1, 0, 1, 0}, dc[4] = {0, 1, 0, -1};
  const int r = cell / sc.cols + dr[d], c = cell % sc.cols + dc[d];
  if (r < 0 || r >= sc.rows || c < 0 || c >= sc.cols || !sc.trav[r * sc.cols + c]) return -1;
  return r * sc.cols + c;
}

// What the tie hook reads.
bool g_replay = false;
const Scenario* g_sc = nullptr;
Graph* g_graph = nullptr;
DistTable* g_dist = nullptr;
const Config* g_from = nullptr;
Stream* g_plan_rng = nullptr;
struct ReplayCall {  // the candidate order of the planner call under way
  int agent = -1, left = 0, k = 0;
  int cand[5] = {0, 0, 0, 0, 0};
} g_call;
long g_hook_errors = 0;

}  // namespace

// The hooked build calls this in place of lacam3's tie-breaker draw: once per neighbour u of
// agent i's cell, in the graph's neighbour order, before the candidates are sorted by distance
// plus this value. In replay mode the value is u's rank in nca-qd's candidate order (below 1,
// so it only orders cells equally near the goal; the agent's own cell is never equally near a
// neighbour on a grid).
float tie_hook(PIBT*, int i, Vertex* u, std::mt19937& mt) {
  if (!g_replay) return get_random_float(mt);
  if (g_call.left == 0) {  // the call's first neighbour: order the candidates as nca-qd does
    const int here = (*g_from)[i]->index;
    int k = 0;
    for (int d = 0; d < 4; ++d) {
      const int v = our_neighbor(*g_sc, here, d);
      if (v >= 0) g_call.cand[k++] = v;
    }
    g_call.cand[k++] = here;
    for (int x = k - 1; x > 0; --x) std::swap(g_call.cand[x], g_call.cand[g_plan_rng->below(x + 1)]);
    const std::vector<int>& dist = g_dist->table[i];
    std::stable_sort(g_call.cand, g_call.cand + k,
                     [&](int a, int b) { return dist[g_graph->U[a]->id] < dist[g_graph->U[b]->id]; });
    g_call.k = k;
    g_call.agent = i;
    g_call.left = k - 1;  // the neighbours; the own cell gets no hook call
  }
  if (g_call.agent != i) ++g_hook_errors;
  --g_call.left;
  for (int r = 0; r < g_call.k; ++r)
    if (g_call.cand[r] == u->index) return 0.15f * r;
  ++g_hook_errors;
  return 0.f;
}

namespace {

struct Options {
  std::string scen, map, trace, ties = "lacam";
  int agents = 0, horizon = 0, replan = 5;
  uint64_t seed = 0;
};

[[noreturn]] void usage() {
  std::cerr << "driver --scen F.scen --map F.map --agents N --T T --seed S [--replan 5]"
               " [--ties lacam|replay] [--trace FILE]\n";
  std::exit(2);
}

Options parse(int argc, char** argv) {
  Options o;
  for (int a = 1; a < argc; ++a) {
    const std::string key = argv[a];
    if (a + 1 >= argc) usage();
    const std::string val = argv[++a];
    if (key == "--scen") o.scen = val;
    else if (key == "--map") o.map = val;
    else if (key == "--agents") o.agents = std::stoi(val);
    else if (key == "--T") o.horizon = std::stoi(val);
    else if (key == "--seed") o.seed = std::stoull(val);
    else if (key == "--replan") o.replan = std::stoi(val);
    else if (key == "--ties") o.ties = val;
    else if (key == "--trace") o.trace = val;
    else usage();
  }
  if (o.scen.empty() || o.map.empty() || o.agents <= 0 || o.horizon <= 0 || o.replan < 1) usage();
  if (o.ties != "lacam" && o.ties != "replay") usage();
  return o;
}

struct Agent {
  int cell = 0, phase = 0, stayed = 0, elapsed = 0;
  Task goal;
  bool arrived = false, tasking = false;
  double tie = 0;
};

struct Counts {
  long finished = 0, top_failures = 0, violations = 0, table_mismatch = 0;
  bool congested = false;
  int stop_time = 0;
};

// Checks one step: every agent placed on its cell or a neighbour, no two on one cell, no two
// swapping cells. Returns the number of violations.
long check_step(const Config& from, Config& to, std::vector<int>& owner) {
  long bad = 0;
  const int n = static_cast<int>(from.size());
  for (int a = 0; a < n; ++a) {
    if (to[a] == nullptr) ++bad, to[a] = from[a];
    bool adjacent = to[a] == from[a];
    for (Vertex* u : from[a]->neighbor) adjacent |= u == to[a];
    if (!adjacent) ++bad;
    if (owner[to[a]->index] >= 0) ++bad;
    owner[to[a]->index] = a;
  }
  for (int a = 0; a < n; ++a) {
    const int b = owner[from[a]->index];
    if (b >= 0 && b != a && to[a] == from[b]) ++bad;
  }
  for (int a = 0; a < n; ++a) owner[to[a]->index] = -1;
  return bad;
}

// One planner step: lacam3 stops at the first agent it cannot place; a lifelong step needs all
// placed, so it is called again with what was decided as constraints (nca-qd's loop goes on
// to the next agent, which is the same). Returns false if a call makes no progress.
bool plan_step(PIBT& pibt, const Config& from, Config& to, const std::vector<int>& order, Counts& c) {
  bool ok = pibt.set_new_config(from, to, order);
  while (!ok) {
    ++c.top_failures;
    const long open = std::count(to.begin(), to.end(), nullptr);
    if (open == 0) return true;
    ok = pibt.set_new_config(from, to, order);
    if (!ok && std::count(to.begin(), to.end(), nullptr) == open) return false;
  }
  return true;
}

Counts simulate(const Options& o, const Scenario& sc, Graph* G, std::FILE* trace) {
  const int N = o.agents, cells = sc.rows * sc.cols;
  Stream rng(o.seed), plan_rng(o.seed ^ 0x5DEECE66DULL);
  std::vector<int> free_cells;
  for (int c = 0; c < cells; ++c)
    if (sc.trav[c]) free_cells.push_back(c);
  if (N > static_cast<int>(free_cells.size())) throw std::runtime_error("more agents than free cells");
  for (int a = 0; a < N; ++a) std::swap(free_cells[a], free_cells[a + rng.below(free_cells.size() - a)]);
  std::vector<Agent> ag(N);
  for (int a = 0; a < N; ++a) {
    ag[a].cell = free_cells[a];
    ag[a].tie = plan_rng.uniform();
    ag[a].goal = draw_task(sc, rng, ag[a].phase);
  }

  Config starts(N), goals(N);
  for (int a = 0; a < N; ++a) starts[a] = G->U[ag[a].cell], goals[a] = G->U[ag[a].goal.cell];
  Instance ins(G, starts, goals, N);
  ins.delete_graph_after_used = false;  // (that constructor leaves it unset)
  DistTable D(ins);
  std::vector<std::vector<int>> row_of(cells);
  auto goal_row = [&](int cell) -> const std::vector<int>& {
    if (row_of[cell].empty()) {
      Instance one(G, Config{G->U[cell]}, Config{G->U[cell]}, 1);
      one.delete_graph_after_used = false;
      row_of[cell] = DistTable(one).table[0];
    }
    return row_of[cell];
  };
  Counts c;
  for (int a = 0; a < N; ++a) c.table_mismatch += D.table[a] != goal_row(ag[a].goal.cell);

  PIBT pibt(&ins, &D, static_cast<int>(o.seed), true, nullptr);
  Config from(N), to(N);
  g_sc = &sc, g_graph = G, g_dist = &D, g_plan_rng = &plan_rng, g_from = &from;
  std::vector<int> order(N), round_start(N), owner(cells, -1), snapshot(N);
  std::vector<char> stuck(N);
  std::iota(order.begin(), order.end(), 0);
  auto write_trace = [&]() {
    if (!trace) return;
    for (int a = 0; a < N; ++a) snapshot[a] = ag[a].cell;
    std::fwrite(snapshot.data(), sizeof(int), N, trace);
  };
  write_trace();
  int t = 0;
  while (t < o.horizon) {
    const int steps = std::min(o.replan, o.horizon - t);
    for (int a = 0; a < N; ++a) round_start[a] = ag[a].cell, stuck[a] = !ag[a].tasking;
    for (int s = 1; s <= steps; ++s) {
      std::sort(order.begin(), order.end(), [&](int x, int y) {
        if (ag[x].elapsed != ag[y].elapsed) return ag[x].elapsed > ag[y].elapsed;
        if (ag[x].tie != ag[y].tie) return ag[x].tie > ag[y].tie;
        return x < y;
      });
      for (int a = 0; a < N; ++a) {
        from[a] = G->U[ag[a].cell];
        to[a] = ag[a].arrived && ag[a].stayed < ag[a].goal.dwell ? from[a] : nullptr;
      }
      g_call.left = 0;
      if (!plan_step(pibt, from, to, order, c))
        throw std::runtime_error("no progress at t=" + std::to_string(t + s - 1));
      c.violations += check_step(from, to, owner);
      for (int a = 0; a < N; ++a) {  // goal bookkeeping: RHCR's rules, as nca-qd's core
        Agent& x = ag[a];
        x.cell = to[a]->index;
        x.tasking = false;
        ++x.elapsed;
        if (x.goal.cell != x.cell) x.arrived = false;
        else if (x.arrived) ++x.stayed, x.tasking = x.goal.dwell > 0;
        else x.arrived = true, x.stayed = 0;
        if (s < o.replan && (x.cell != round_start[a] || x.tasking)) stuck[a] = 0;
        while (x.arrived && x.stayed >= x.goal.dwell) {
          ++c.finished;
          x.arrived = false;
          x.goal = draw_task(sc, rng, x.phase);
          x.elapsed = 0;
          ins.goals[a] = G->U[x.goal.cell];
          D.table[a] = goal_row(x.goal.cell);
          if (x.goal.cell == x.cell) x.arrived = true, x.stayed = 0;
        }
      }
      write_trace();
    }
    t += steps;
    if (2 * std::count(stuck.begin(), stuck.end(), 1) > N) {
      c.congested = true;
      break;
    }
  }
  c.stop_time = t;
  return c;
}

}  // namespace

int main(int argc, char** argv) {
  const Options o = parse(argc, argv);
#ifndef HOOKED
  if (o.ties != "lacam") {
    std::cerr << "--ties " << o.ties << " needs the hooked build (hook_pibt.cpp)\n";
    return 2;
  }
#endif
  g_replay = o.ties == "replay";
  try {
    const std::clock_t cpu0 = std::clock();
    const Scenario sc = read_scenario(o.scen);
    Graph G(o.map);  // lacam3's own loader
    if (G.width != sc.cols || G.height != sc.rows) throw std::runtime_error("map and scenario sizes differ");
    for (int c = 0; c < sc.rows * sc.cols; ++c)
      if ((G.U[c] != nullptr) != static_cast<bool>(sc.trav[c])) throw std::runtime_error("map and scenario masks differ");
    std::FILE* trace = o.trace.empty() ? nullptr : std::fopen(o.trace.c_str(), "wb");
    if (!o.trace.empty() && !trace) throw std::runtime_error("cannot write " + o.trace);
    const Counts c = simulate(o, sc, &G, trace);
    if (trace) std::fclose(trace);
    std::printf(
        "finished=%ld throughput=%.6f congested=%d stop_time=%d top_failures=%ld violations=%ld "
        "table_mismatch=%ld hook_errors=%ld cpu_s=%.3f\n",
        c.finished, static_cast<double>(c.finished) / o.horizon, c.congested ? 1 : 0, c.stop_time, c.top_failures,
        c.violations, c.table_mismatch, g_hook_errors, static_cast<double>(std::clock() - cpu0) / CLOCKS_PER_SEC);
  } catch (const std::exception& e) {
    std::cerr << "error: " << e.what() << "\n";
    return 1;
  }
  return 0;
}
