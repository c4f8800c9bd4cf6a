// Python bindings (nanobind): one function, `run`, that releases the GIL while simulating.
#include <nanobind/nanobind.h>
#include <nanobind/ndarray.h>
#include <nanobind/stl/vector.h>

#include <stdexcept>
#include <vector>

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
             int window, int replan, double time_limit_s, int64_t pbs_max_nodes, bool record_paths) {
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

  rhcr::SimResult r;
  {
    nb::gil_scoped_release release;  // simulations in other threads run in parallel
    r = rhcr::simulate(cfg);
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
  d["tasks_per_step"] = to_numpy(std::move(r.tasks_per_step), {static_cast<size_t>(horizon)});
  d["tile_visits"] = to_numpy(std::move(r.tile_visits), {static_cast<size_t>(cfg.rows), static_cast<size_t>(cfg.cols)});
  if (record_paths) d["paths"] = to_numpy(std::move(r.paths), {steps, static_cast<size_t>(n_agents)});
  const size_t n_goals = r.goal_cells.size();
  d["goal_offsets"] = to_numpy(std::move(r.goal_offsets), {static_cast<size_t>(n_agents) + 1});
  d["goal_cells"] = to_numpy(std::move(r.goal_cells), {n_goals});
  d["goal_dwell"] = to_numpy(std::move(r.goal_dwell), {n_goals});
  return d;
}

}  // namespace

NB_MODULE(_core, m) {
  m.doc() = "Compiled RHCR lifelong-MAPF simulator (windowed PBS over space-time A*).";
  m.def("run", &run, "traversable"_a, "class_cells"_a, "class_weights"_a, "class_dwell"_a, "cycle"_a,
        "n_agents"_a, "horizon"_a, "seed"_a, "window"_a = 10, "replan"_a = 5, "time_limit_s"_a = 0.0,
        "pbs_max_nodes"_a = 0, "record_paths"_a = false,
        "Run one simulation; returns a dict of figures and NumPy arrays. Releases the GIL.");
}
