// Python bindings (nanobind): `run` (one simulation) and `plan` (one planning call); both
// release the GIL.
#include <nanobind/nanobind.h>
#include <nanobind/ndarray.h>
#include <nanobind/stl/string.h>
#include <nanobind/stl/vector.h>

#include <stdexcept>
#include <string>
#include <vector>

#include "grid.hpp"
#include "pbs.hpp"
#include "pibt.hpp"
#include "rhcr.hpp"

namespace nb = nanobind;
using namespace nb::literals;

namespace {

// Hand a std::vector to NumPy without copying: the array owns the vector through a capsule.
template <class T>
nb::object to_numpy(std::vector<T>&& v, std::initializer_list<size_t> shape) {
  auto* heap = new std::vector<T>(std::move(v));
  nb::capsule owner(heap, [](void* p) noexcept { delete static_cast<std::vector<T>*>(p); });
  return nb::cast(nb::ndarray<nb::numpy, T>(heap->data(), shape, owner));
}

nb::dict run(nb::ndarray<const uint8_t, nb::ndim<2>, nb::c_contig, nb::device::cpu> traversable,
             std::vector<std::vector<int>> class_cells, std::vector<std::vector<double>> class_weights,
             std::vector<int> class_dwell, std::vector<int> cycle, int n_agents, int horizon, uint64_t seed,
             int window, int replan, double time_limit_s, int64_t pbs_max_nodes, bool record_paths,
             double plan_time_limit_s, bool prioritize_start, bool reference_starts, int64_t plan_max_expansions,
             const std::string& planner) {
  if (planner != "rhcr" && planner != "pibt" && planner != "pibt_swap")
    throw std::invalid_argument("planner must be rhcr, pibt or pibt_swap");
  rhcr::SimConfig cfg;
  cfg.rows = static_cast<int>(traversable.shape(0));
  cfg.cols = static_cast<int>(traversable.shape(1));
  cfg.traversable.assign(traversable.data(), traversable.data() + traversable.size());
  if (class_cells.size() != class_weights.size() || class_cells.size() != class_dwell.size())
    throw std::invalid_argument("class_cells, class_weights and class_dwell differ in length");
  for (size_t i = 0; i < class_cells.size(); ++i)
    cfg.classes.push_back({std::move(class_cells[i]), std::move(class_weights[i]), class_dwell[i]});
  cfg.cycle = std::move(cycle);
  cfg.n_agents = n_agents;
  cfg.horizon = horizon;
  cfg.seed = seed;
  cfg.window = window;
  cfg.replan = replan;
  cfg.time_limit_s = time_limit_s;
  cfg.pbs_max_nodes = pbs_max_nodes;
  cfg.record_paths = record_paths;
  cfg.plan_time_limit_s = plan_time_limit_s;
  cfg.prioritize_start = prioritize_start;
  cfg.reference_starts = reference_starts;
  cfg.plan_max_expansions = plan_max_expansions;

  rhcr::SimResult r;
  {
    nb::gil_scoped_release release;  // simulations in other threads run in parallel
    r = planner == "rhcr" ? rhcr::simulate(cfg) : rhcr::simulate_pibt(cfg, planner == "pibt_swap");
  }
  const size_t steps = static_cast<size_t>(r.stop_time) + 1;
  nb::dict d;
  d["finished_tasks"] = r.finished_tasks;
  d["throughput"] = r.throughput;
  d["success"] = r.success;
  d["congested"] = r.congested;
  d["timed_out"] = r.timed_out;
  d["stop_time"] = r.stop_time;
  d["replans"] = r.replans;
  d["pbs_failures"] = r.pbs_failures;
  d["pbs_nodes"] = r.pbs_nodes;
  d["low_level_expansions"] = r.low_level_expansions;
  d["cpu_seconds"] = r.cpu_seconds;
  d["wall_seconds"] = r.wall_seconds;
  const size_t calls = r.call_nodes.size();
  d["call_nodes"] = to_numpy(std::move(r.call_nodes), {calls});
  d["call_cpu_seconds"] = to_numpy(std::move(r.call_cpu_seconds), {calls});
  d["call_failed"] = to_numpy(std::move(r.call_failed), {calls});
  d["call_expansions"] = to_numpy(std::move(r.call_expansions), {calls});
  d["tasks_per_step"] = to_numpy(std::move(r.tasks_per_step), {static_cast<size_t>(horizon)});
  d["tile_visits"] = to_numpy(std::move(r.tile_visits), {static_cast<size_t>(cfg.rows), static_cast<size_t>(cfg.cols)});
  if (record_paths) d["paths"] = to_numpy(std::move(r.paths), {steps, static_cast<size_t>(n_agents)});
  const size_t n_goals = r.goal_cells.size();
  d["goal_offsets"] = to_numpy(std::move(r.goal_offsets), {static_cast<size_t>(n_agents) + 1});
  d["goal_cells"] = to_numpy(std::move(r.goal_cells), {n_goals});
  d["goal_dwell"] = to_numpy(std::move(r.goal_dwell), {n_goals});
  return d;
}

// One planning call on its own (for tests and side-by-side traces): agents at `starts` with
// goal queues `goals` (cells) with their dwell times `dwells` (empty: all 0), `executed_steps`
// to be executed.
nb::dict plan(nb::ndarray<const uint8_t, nb::ndim<2>, nb::c_contig, nb::device::cpu> traversable,
              std::vector<int> starts, std::vector<std::vector<int>> goals, int window, int executed_steps,
              int64_t max_nodes, double time_limit_s, bool prioritize_start, uint64_t seed,
              std::vector<std::vector<int>> dwells) {
  const int rows = static_cast<int>(traversable.shape(0)), cols = static_cast<int>(traversable.shape(1));
  const int n = static_cast<int>(starts.size());
  if (static_cast<int>(goals.size()) != n) throw std::invalid_argument("one goal list per start");
  if (window < 1 || executed_steps < 1 || executed_steps > window)
    throw std::invalid_argument("need 1 <= executed_steps <= window");
  std::vector<uint8_t> free(traversable.data(), traversable.data() + traversable.size());
  for (int c : starts)
    if (c < 0 || c >= rows * cols || !free[c]) throw std::invalid_argument("start off the traversable tiles");
  for (const auto& g : goals) {
    if (g.empty()) throw std::invalid_argument("every agent needs a goal");
    for (int c : g)
      if (c < 0 || c >= rows * cols || !free[c]) throw std::invalid_argument("goal off the traversable tiles");
  }
  if (!dwells.empty()) {
    if (dwells.size() != goals.size()) throw std::invalid_argument("one dwell list per goal list");
    for (int a = 0; a < n; ++a) {
      if (dwells[a].size() != goals[a].size()) throw std::invalid_argument("one dwell per goal");
      for (int d : dwells[a])
        if (d < 0) throw std::invalid_argument("dwell must be >= 0");
    }
  }
  rhcr::Grid grid(rows, cols, std::move(free));
  rhcr::DistanceCache distances(grid);
  std::vector<rhcr::AgentQuery> queries(n);
  for (int a = 0; a < n; ++a) {
    queries[a].start = starts[a];
    queries[a].min_end = executed_steps;
    for (size_t i = 0; i < goals[a].size(); ++i) {
      queries[a].goals.push_back({goals[a][i], dwells.empty() ? 0 : dwells[a][i]});
      queries[a].dist.push_back(distances.get(goals[a][i]));
    }
  }
  rhcr::WindowedPBS pbs(grid, n, window);
  rhcr::PbsLimits limits;
  limits.max_nodes = max_nodes;
  limits.time_limit_s = time_limit_s;
  limits.prioritize_start = prioritize_start;
  rhcr::Rng rng(seed);
  std::vector<int> paths;
  bool solved;
  {
    nb::gil_scoped_release release;
    solved = pbs.solve(queries, executed_steps, limits, rng, paths);
  }
  nb::dict d;
  d["solved"] = solved;
  d["nodes"] = pbs.stats().nodes_expanded;
  d["paths"] = to_numpy(std::move(paths), {static_cast<size_t>(n), static_cast<size_t>(window) + 1});
  return d;
}

}  // namespace

NB_MODULE(_core, m) {
  m.doc() = "Compiled lifelong-MAPF simulators: RHCR (windowed PBS over space-time A*) and PIBT.";
  m.attr("VERSION") = 4;  // bump when a change alters simulated outcomes
  m.def("run", &run, "traversable"_a, "class_cells"_a, "class_weights"_a, "class_dwell"_a, "cycle"_a,
        "n_agents"_a, "horizon"_a, "seed"_a, "window"_a = 10, "replan"_a = 5, "time_limit_s"_a = 0.0,
        "pbs_max_nodes"_a = 0, "record_paths"_a = false, "plan_time_limit_s"_a = 60.0,
        "prioritize_start"_a = true, "reference_starts"_a = false, "plan_max_expansions"_a = 0,
        "planner"_a = "rhcr",
        "Run one simulation (planner rhcr: windowed PBS; pibt: lifelong PIBT; pibt_swap: PIBT with swap); returns a dict of figures and NumPy arrays. Releases the GIL.");
  m.def("plan", &plan, "traversable"_a, "starts"_a, "goals"_a, "window"_a = 10, "executed_steps"_a = 5,
        "max_nodes"_a = 0, "time_limit_s"_a = 60.0, "prioritize_start"_a = true, "seed"_a = 0,
        "dwells"_a = std::vector<std::vector<int>>(),
        "One windowed PBS call: dict(solved, nodes, paths [agents, window + 1], -1 after a path's end).");
}
