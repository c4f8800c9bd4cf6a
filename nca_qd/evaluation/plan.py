"""The evaluation's plan: its settings checked (:func:`validated`), then every size, agent
count and run count of the tables and curves (:class:`Plan`), from which the simulation
requests of the layouts follow (:meth:`Plan.requests`). The plan is what the stages read:
typed settings (the selection, the screen, the exact runs), the NCA iterations and the repair
options of each size, built once here from ``evaluate.yaml`` and the run's domain.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import Any, NamedTuple

from nca_qd.errors import NcaQdError, require_bool
from nca_qd.evaluation.agents import agent_range, positive_ints, scaled_agents
from nca_qd.evaluation.records import EvalLayout, Request, full_shape, parse_size, size_map, size_str
from nca_qd.layouts import get_layout
from nca_qd.scoring.jobs import ExactSettings


def records_from(value: Any) -> list[str]:
    """``records_from``: a list of existing folders (one clear error otherwise)."""
    from pathlib import Path

    if value is None:
        return []
    if isinstance(value, str) or not isinstance(value, Sequence):
        raise NcaQdError(f"records_from must be a list of evaluation folders, got {value!r}")
    for folder in value:
        if not isinstance(folder, str) or not Path(folder).is_dir():
            raise NcaQdError(f"records_from: {folder!r} is not a folder")
    return [str(f) for f in value]


# Settings added after evaluations were recorded, with the value those evaluations ran with:
# filled in where an older evaluate_config.yaml lacks them (here and in experiments.compare).
ADDED_LATER = {"baselines.tiling_draws": 1, "select.exact_top": 0, "select.exact_runs": 2, "detail": True}


def validated(ecfg: Mapping[str, Any]) -> dict[str, Any]:
    """Plain copy of the config with its numbers checked (one clear error each)."""
    e = dict(ecfg)

    def pos(path: str, allow_zero: bool = False) -> None:
        node: Any = e
        for k in path.split("."):
            node = node[k]
        low = 0 if allow_zero else 1
        if isinstance(node, bool) or not isinstance(node, int) or node < low:
            raise NcaQdError(f"{path} must be an integer >= {low}, got {node!r}")

    if not e.get("run_dir"):
        raise NcaQdError("give run_dir=<run directory>")
    for p in (
        "T",
        "runs.train",
        "runs.eval",
        "sweep.train.runs",
        "sweep.eval.runs",
        "sizes.runs",
        "sizes.round_to",
        "exact.window",
        "exact.replan",
        "screen.replan",
    ):
        pos(p)
    for p in ("exact.train", "exact.eval", "exact.sweep_train", "exact.sweep_eval", "exact.sizes", "seed"):
        pos(p, allow_zero=True)
    tl = e["exact"].get("time_limit_s")
    if tl is not None and (isinstance(tl, bool) or not isinstance(tl, (int, float)) or tl <= 0):
        raise NcaQdError(f"exact.time_limit_s must be a positive number or null, got {tl!r}")
    e["repair"] = dict(e.get("repair") or {})
    for part in ("exact", "screen", "repair"):
        require_bool(f"{part}.reuse", e[part].setdefault("reuse", True))
    require_bool("prune_records", e.setdefault("prune_records", True))
    require_bool("detail", e.setdefault("detail", ADDED_LATER["detail"]))
    e["records_from"] = records_from(e.get("records_from"))
    from nca_qd.sim.rhcr import planner_options

    planner_options(e["exact"], "exact.")
    sel = e.setdefault("select", {"by": "s", "pool": 10, "runs": 2, "T": 1000})
    backfill = {k.split(".")[1]: v for k, v in ADDED_LATER.items() if k.startswith("select.")}
    sel = e["select"] = {**backfill, **sel}
    if sel.get("by") not in ("s", "s_eval"):
        raise NcaQdError(f"select.by must be s or s_eval, got {sel.get('by')!r}")
    if sel["by"] == "s_eval":
        for p in ("select.pool", "select.runs", "select.T", "select.exact_runs"):
            pos(p)
        pos("select.exact_top", allow_zero=True)
        if sel["exact_top"] > sel["pool"]:
            raise NcaQdError(f"select.exact_top ({sel['exact_top']}) exceeds select.pool ({sel['pool']})")
        if isinstance(e["elites"], bool) or not isinstance(e["elites"], int):
            raise NcaQdError(
                f"select.by=s_eval picks a number of elites; elites must be a count, got {e['elites']!r}"
            )
        if e["elites"] > sel["pool"]:
            raise NcaQdError(f"elites ({e['elites']}) exceeds select.pool ({sel['pool']})")
    e["baselines"] = dict(e["baselines"])
    e["baselines"].setdefault("tiling_draws", ADDED_LATER["baselines.tiling_draws"])
    pos("baselines.tiling_draws")
    shelves = e.setdefault("n_shelves", {"train": None, "eval": None})
    for k in ("train", "eval"):
        if shelves.get(k) is not None:
            pos(f"n_shelves.{k}")
    if e["screen"]["where"] not in ("all", "rest"):
        raise NcaQdError(f"screen.where must be all or rest, got {e['screen']['where']!r}")
    for k in ("train", "eval"):
        if e["exact"][k] > e["runs"][k]:
            raise NcaQdError(f"exact.{k} ({e['exact'][k]}) exceeds runs.{k} ({e['runs'][k]})")
    return e


def interpolate_iters(
    full: Sequence[int], s_train: Sequence[int], s_eval: Sequence[int], c_train: int, c_eval: int
) -> int:
    """NCA iterations for a size between S and S_eval: linear in the map's side (square root
    of its area) between C at S and C_eval at S_eval, extrapolated beyond, at least 1."""
    side = math.sqrt(full[0] * full[1])
    a, b = math.sqrt(s_train[0] * s_train[1]), math.sqrt(s_eval[0] * s_eval[1])
    if b == a:
        return int(c_eval if side > a else c_train)
    return max(1, int(round(c_train + (side - a) / (b - a) * (c_eval - c_train))))


def exact_settings(exact_cfg: Mapping[str, Any], T: int) -> ExactSettings:
    """The evaluation's exact runs as one :class:`~nca_qd.scoring.jobs.ExactSettings`: its
    ``exact`` block (window, replanning period, wall-clock limit, planner knobs) and ``T``."""
    from nca_qd.sim.rhcr import planner_options

    return ExactSettings(
        int(T),
        exact_cfg.get("time_limit_s"),
        int(exact_cfg["window"]),
        int(exact_cfg["replan"]),
        planner_options(exact_cfg, "exact."),
    )


class SelectSettings(NamedTuple):
    """``select``: how the generators to evaluate are picked (``by``: s | s_eval; with s_eval,
    the ``exact_top`` best by the screen checked by ``exact_runs`` exact runs each)."""

    by: str
    pool: int
    runs: int
    T: int
    exact_top: int = 0
    exact_runs: int = 2


class ScreenSettings(NamedTuple):
    """``screen``: where the screen runs (all | rest), its check period, crowding threshold
    (the evaluation's, else the run's domain's) and CPU threads, and whether recorded runs are
    reused."""

    where: str
    replan: int
    crowd_mean: float
    threads: int | None
    reuse: bool


class Plan:
    """Sizes, agent counts and run counts of every table and curve. With ``scales=False``
    (the layouts of a direct search, DSAGE, exist at S only) every size but S is dropped: no
    S_eval table or curve, no tiling baseline, the more-sizes curve reduced to S."""

    def __init__(self, e: Mapping[str, Any], d: Mapping[str, Any], name: str, scales: bool = True):
        from nca_qd.sim.screen import crowd_mean_for

        self.e, self.d, self.name, self.scales = e, d, name, scales
        self.T, self.seed = int(e["T"]), int(e["seed"])
        self.tasks_smooth, self.progress = int(e["tasks_smooth"]), require_bool("progress", e["progress"])
        self.detail = bool(e["detail"])  # keep the main runs' tasks per step and tile visits
        sel = e["select"]
        self.select = SelectSettings(
            str(sel["by"]),
            int(sel["pool"]),
            int(sel["runs"]),
            int(sel["T"]),
            int(sel["exact_top"]),
            int(sel["exact_runs"]),
        )
        self.elites = e["elites"]  # a count, or a list of cells
        self.human_baseline = require_bool("baselines.human", e["baselines"]["human"])
        self.tiling_baseline = require_bool("baselines.tiling", e["baselines"]["tiling"])
        self.tiling_from = str(e["baselines"].get("tiling_from", "repaired"))
        if self.tiling_from not in ("repaired", "unrepaired"):
            raise NcaQdError(
                f"baselines.tiling_from must be repaired or unrepaired, got {self.tiling_from!r}"
            )
        self.tiling_draws = int(e["baselines"].get("tiling_draws", 1))
        sc = e["screen"]
        self.screen = ScreenSettings(
            str(sc["where"]),
            int(sc["replan"]),
            crowd_mean_for(d, sc.get("crowd_mean")),
            sc.get("threads"),
            bool(sc["reuse"]),
        )
        self.exact = exact_settings(e["exact"], self.T)
        self.select_exact = exact_settings(e["exact"], self.select.T)  # the selection's exact check
        self.exact_reuse = bool(e["exact"]["reuse"])
        self.repair_reuse = bool(e["repair"]["reuse"])
        self.repair_overrides = {k: v for k, v in e["repair"].items() if v is not None and k != "reuse"}
        self.s_train = full_shape(name, d["size"]["train"])
        self.s_eval = full_shape(name, d["size"]["eval"])
        shelves = [k for k, v in (e.get("n_shelves") or {}).items() if v is not None]
        if shelves and not get_layout(name).construction.exact_count:  # no fixed shelf count N_s
            raise NcaQdError(f"n_shelves.{shelves[0]}: {name} has no shelves (warehouse domains only)")
        self.n_train = int(e["agents"]["train"] or d["n_agents"]["train"])
        self.n_eval = int(e["agents"]["eval"] or d["n_agents"]["eval"])
        self.sweep_train = agent_range(e["sweep"]["train"], self.n_train, 10, "sweep.train")
        self.sweep_eval = agent_range(
            e["sweep"]["eval"], self.n_eval, get_layout(name).eval_agent_step, "sweep.eval"
        )
        self.sweep_exact = {
            which: _exact_points(e["sweep"][which].get("exact_agents"), points, f"sweep.{which}")
            for which, points in (("train", self.sweep_train), ("eval", self.sweep_eval))
        }
        sz = e["sizes"]
        extra = [tuple(positive_ints(s, "sizes.shapes")) for s in sz["shapes"]]
        for s in extra:
            if len(s) != 2:
                raise NcaQdError(f"sizes.shapes entries must be [rows, cols], got {list(s)}")
        curve = list(extra)
        if require_bool("sizes.include_main", sz["include_main"]):
            curve = [self.s_train, *curve, self.s_eval]
        self.curve = list(dict.fromkeys(curve))  # map sizes on the "more sizes" curve
        self.extra = [s for s in dict.fromkeys(extra) if s not in (self.s_train, self.s_eval)]
        ref_n = int(sz.get("reference_agents") or self.n_eval)
        fr = sz["fractions"]
        if not fr or any(isinstance(f, bool) or not isinstance(f, (int, float)) or f <= 0 for f in fr):
            raise NcaQdError(f"sizes.fractions must be positive numbers, got {fr!r}")
        explicit = {
            parse_size(k): positive_ints(v, f"sizes.agents.{k}") for k, v in size_map(sz, "agents").items()
        }
        for key in ("agents", "nca_iters", "n_shelves"):
            stray = [k for k in size_map(sz, key) if parse_size(k) not in self.curve]
            if stray:
                raise NcaQdError(
                    f"sizes.{key} names {', '.join(map(str, stray))}, not a size "
                    f"of the curve ({', '.join(size_str(s) for s in self.curve)})"
                )
        self.curve_agents = {
            s: explicit.get(s) or scaled_agents(s, ref_n, self.s_eval, sz["fractions"], int(sz["round_to"]))
            for s in self.curve
        }
        if not scales:
            self.extra, self.curve = [], [s for s in self.curve if s == self.s_train]
            self.curve_agents = {s: n for s, n in self.curve_agents.items() if s in self.curve}
        # the sizes layouts are generated at
        self.sizes = list(
            dict.fromkeys([self.s_train] if not scales else [self.s_train, self.s_eval, *self.extra])
        )
        self.all_sizes = [size_str(s) for s in self.sizes]
        if self.tiling_draws > 1 and self.repair_options(self.s_eval).get("tie_break") != "random":
            # with tie_break none every draw is the same layout: k runs of one repair
            raise NcaQdError(
                f"baselines.tiling_draws={self.tiling_draws} needs repair.tie_break=random "
                "(each draw is a repair seed; without random tie costs they all give one layout)"
            )

    def which(self, shape: tuple[int, int]) -> str:
        return "train" if shape == self.s_train else "eval" if shape == self.s_eval else "extra"

    def most_agents(self, shape: tuple[int, int]) -> int:
        """The most agents any table or curve puts on a map of this size."""
        ns = list(self.curve_agents.get(shape, []))
        if shape == self.s_train:
            ns += [self.n_train, *self.sweep_train]
        if shape == self.s_eval:
            ns += [self.n_eval, *self.sweep_eval]
        return max(ns) if ns else 1

    def nca_iters(self, shape: tuple[int, int]) -> int:
        """NCA iterations at a full-map size: C at S, C_eval at S_eval, ``sizes.nca_iters`` or
        linear in the map's side between them elsewhere."""
        c_train, c_eval = int(self.d["nca_iters"]["train"]), int(self.d["nca_iters"]["eval"])
        which = self.which(shape)
        if which != "extra":
            return c_train if which == "train" else c_eval
        given = {
            parse_size(k): positive_ints(v, f"sizes.nca_iters.{k}")[0]
            for k, v in size_map(self.e["sizes"], "nca_iters").items()
        }
        return given.get(shape) or interpolate_iters(shape, self.s_train, self.s_eval, c_train, c_eval)

    def repair_options(self, shape: tuple[int, int]) -> dict[str, Any]:
        """Repair options at a full-map size: the run's (train or eval block; N_s from this
        command's ``n_shelves`` where given), N_s of the human layout at other sizes (or
        ``sizes.n_shelves``), traversable >= the most agents simulated (manufacturing), then
        this command's ``repair`` overrides."""
        from nca_qd.scoring.jobs import repair_options

        which = self.which(shape)
        opts = repair_options(self.d, "train" if which == "train" else "eval")
        if which == "extra":
            opts.pop("n_shelves", None)
            n_s = size_map(self.e["sizes"], "n_shelves").get(size_str(shape))
        else:
            n_s = (self.e.get("n_shelves") or {}).get(which)
        if n_s is not None:
            opts["n_shelves"] = int(n_s)
        opts["n_agents"] = max(int(opts.get("n_agents", 0)), self.most_agents(shape))
        opts.update(self.repair_overrides)
        return opts

    def _sweep_exact(self, which: str, n: int) -> int:
        """Exact runs at agent count ``n`` of the ``which`` curve: exact.sweep_<which> where
        sweep.<which>.exact_agents names ``n`` (or is null), else none."""
        at = self.sweep_exact[which]
        return int(self.e["exact"][f"sweep_{which}"]) if at is None or n in at else 0

    def requests(self, layouts: Mapping[str, EvalLayout]) -> list[Request]:
        e, ex, detail = self.e, self.e["exact"], self.detail
        out: list[Request] = []
        for key, lay in layouts.items():
            if lay.layout is None:
                continue
            shape = lay.layout.shape
            if shape == self.s_train:
                out.append(Request("main_train", key, self.n_train, e["runs"]["train"], ex["train"], detail))
                out += [
                    Request("sweep_train", key, n, e["sweep"]["train"]["runs"], self._sweep_exact("train", n))
                    for n in self.sweep_train
                ]
            if shape == self.s_eval and self.scales:
                out.append(Request("main_eval", key, self.n_eval, e["runs"]["eval"], ex["eval"], detail))
                out += [
                    Request("sweep_eval", key, n, e["sweep"]["eval"]["runs"], self._sweep_exact("eval", n))
                    for n in self.sweep_eval
                ]
            if shape in self.curve_agents and lay.kind != "tiling":
                out += [
                    Request("sizes", key, n, e["sizes"]["runs"], ex["sizes"])
                    for n in self.curve_agents[shape]
                ]
        return out


def _exact_points(spec: Any, points: Sequence[int], where: str) -> set[int] | None:
    """The agent counts of a curve named by ``<where>.exact_agents`` (None: all of them); each
    must be a point of the curve."""
    if spec is None:
        return None
    at = set(positive_ints(spec, f"{where}.exact_agents"))
    off = sorted(at - set(points))
    if off:
        curve = f"{points[0]} … {points[-1]} agents" if points else "the curve is off"
        raise NcaQdError(f"{where}.exact_agents names {off[0]}, not a point of the curve ({curve})")
    return at
