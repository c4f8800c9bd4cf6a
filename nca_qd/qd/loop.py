"""The QD loop: ask -> evaluate -> add to both archives -> tell, state in, state out.

Domain-agnostic: it searches over flat parameter vectors with any batched objective
``f(solutions [b, d], key, context) -> EvalBatch`` (objective, measures, optionally a separate
result objective and validity masks; ``context`` lets a scorer look up the result archive's
elites, which the multi-agent domains use to decide where exact simulation is worth it). ``ask`` and
``add + tell`` are each one jitted call;
the evaluation between them is the domain's (a jitted JAX function for the maze, a host-side
pipeline of repair and simulation for the warehouse).

QD-score: sum over occupied cells of ``f - offset`` where ``offset`` is the lowest objective the
domain can produce (``objective_range[0]`` in its config), so an empty cell counts 0 and every
elite counts a non-negative amount.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import chex
import flax.struct
import jax
import jax.numpy as jnp
import numpy as np

from nca_qd.interfaces import Emitter, EvalBatch, ScoringContext
from nca_qd.qd.archive import ThresholdRepertoire, archive_stats, grid_cell_indices

Objective = Callable[..., EvalBatch]  # (solutions [b, d], key, context) -> EvalBatch


class QDState(flax.struct.PyTreeNode):
    """Everything a run needs to continue: archives, emitter state, key and counters."""

    opt_archive: ThresholdRepertoire
    res_archive: ThresholdRepertoire
    emitter_state: Any
    key: jax.Array
    iteration: jax.Array
    evaluations: jax.Array


@dataclass(frozen=True)
class ArchiveSpec:
    """Grid and thresholds shared by both archives."""

    cells: Sequence[int]
    ranges: Sequence[Sequence[float]]
    learning_rate: float = 1.0
    threshold_min: float = -float("inf")
    qd_offset: float = 0.0


class QDLoop:
    """Runs one QD algorithm (an emitter, see :mod:`nca_qd.qd.emitters`) on an objective."""

    def __init__(self, emitter: Emitter, objective: Objective, dim: int, spec: ArchiveSpec):
        self.emitter, self.objective, self.dim, self.spec = emitter, objective, dim, spec
        self.batch_size = emitter.batch_size
        self._ask = jax.jit(self._ask_impl)
        self._update = jax.jit(self._update_impl)

    def init(self, key: jax.Array) -> QDState:
        k_emit, k_run = jax.random.split(key)
        return QDState(
            opt_archive=ThresholdRepertoire.create(
                self.dim, self.spec.cells, self.spec.ranges, self.spec.learning_rate, self.spec.threshold_min
            ),
            res_archive=ThresholdRepertoire.create(self.dim, self.spec.cells, self.spec.ranges),
            emitter_state=self.emitter.init(k_emit),
            key=k_run,
            iteration=jnp.zeros((), jnp.int32),
            evaluations=jnp.zeros((), jnp.int32),
        )

    def _ask_impl(self, state: QDState):
        key, k_ask, k_eval = jax.random.split(state.key, 3)
        solutions, emitter_state = self.emitter.ask(state.emitter_state, state.opt_archive, k_ask)
        return solutions, k_eval, state.replace(key=key, emitter_state=emitter_state)

    def _update_impl(
        self, state: QDState, solutions, objective, result_objective, measures, valid, result_valid
    ):
        chex.assert_shape(solutions, (self.batch_size, self.dim))
        chex.assert_shape([objective, result_objective, valid, result_valid], (self.batch_size,))
        chex.assert_shape(measures, (self.batch_size, len(self.spec.cells)))
        key, k_tell = jax.random.split(state.key)
        opt_archive, res_archive, f_opt, info, metrics = add_to_archives(
            state, solutions, objective, result_objective, measures, valid, result_valid, self.spec
        )
        emitter_state = self.emitter.tell(state.emitter_state, opt_archive, solutions, f_opt, info, k_tell)
        new = state.replace(
            opt_archive=opt_archive,
            res_archive=res_archive,
            emitter_state=emitter_state,
            key=key,
            iteration=state.iteration + 1,
            evaluations=state.evaluations + self.batch_size,
        )
        return new, metrics

    def context(self, state: QDState) -> ScoringContext:
        """What a scorer may ask of the search: the result archive's elite in a cell."""
        return scoring_context(state, self.spec)

    def step(self, state: QDState) -> tuple[QDState, dict[str, float], EvalBatch]:
        """One iteration; returns the new state, scalar metrics and the batch's evaluation."""
        t0 = time.perf_counter()
        solutions, k_eval, state = self._ask(state)
        ev = self.objective(solutions, k_eval, self.context(state))
        state, metrics = self._update(
            state,
            solutions,
            jnp.asarray(ev.objective),
            jnp.asarray(ev.result_objective),
            jnp.asarray(ev.measures),
            jnp.asarray(ev.valid),
            jnp.asarray(ev.result_valid),
        )
        return state, step_metrics(metrics, ev, state, t0), ev


def step_metrics(
    metrics: Mapping[str, Any],
    ev: EvalBatch,
    state: QDState,
    t0: float,
    extra: Mapping[str, Any] | None = None,
) -> dict[str, float]:
    """One iteration's row of ``metrics.csv``: the archives' metrics, the algorithm's
    ``extra`` and the scorer's own figures as plain numbers, the counters and the seconds since
    ``t0``."""
    out: dict[str, Any] = {k: float(v) for k, v in jax.device_get(dict(metrics)).items()}
    for k, v in [*dict(extra or {}).items(), *dict(ev.extras.get("metrics", {})).items()]:
        out[k] = v if isinstance(v, int) else float(v)
    out["iteration"] = int(state.iteration)
    out["evaluations"] = int(state.evaluations)
    out["step_seconds"] = time.perf_counter() - t0
    return out


def add_to_archives(
    state: QDState, solutions, objective, result_objective, measures, valid, result_valid, spec
):
    """Insert a scored batch into both archives (jittable): f_opt where valid, f_res where also
    ``result_valid``, -inf (never inserted) elsewhere. Returns the new optimisation and result
    archives, f_opt, the optimisation archive's :class:`AddInfo` and the scalar metrics (both
    archives' QD-score, coverage, best objective and size, the batch's best f_res and how
    many it added to the optimisation archive)."""
    f_opt = jnp.where(valid, objective, -jnp.inf).astype(jnp.float32)
    f_res = jnp.where(valid & result_valid, result_objective, -jnp.inf).astype(jnp.float32)
    measures = measures.astype(jnp.float32)
    cells = grid_cell_indices(measures, spec.cells, spec.ranges)
    opt_archive, info = state.opt_archive.add_with_info(solutions, measures, f_opt, cells)
    res_archive, _ = state.res_archive.add_with_info(solutions, measures, f_res, cells)
    res, opt = archive_stats(res_archive, spec.qd_offset), archive_stats(opt_archive, spec.qd_offset)
    metrics = {
        **res,
        **{f"opt_{k}": v for k, v in opt.items()},
        "batch_best": jnp.max(f_res),
        "batch_added": jnp.sum(info.status > 0),
    }
    return opt_archive, res_archive, f_opt, info, metrics


def scoring_context(state: QDState, spec: ArchiveSpec) -> ScoringContext:
    """The :class:`ScoringContext` of a search state: its result archive's elite objective in
    the cell of any measures, and the iteration about to be scored."""
    fitness = state.res_archive.fitnesses[:, 0]

    def result_elite(measures: np.ndarray) -> np.ndarray:
        cells = grid_cell_indices(jnp.asarray(measures, jnp.float32), spec.cells, spec.ranges)
        return np.asarray(fitness[cells], dtype=np.float64)

    return ScoringContext(result_elite=result_elite, iteration=int(state.iteration) + 1)


def make_emitter(algo_cfg: Any, qd_cfg: Any, dim: int):
    """Build the emitter of ``algo.name`` (cma_mae | map_elites | cma_es) from configs."""
    from nca_qd.errors import NcaQdError
    from nca_qd.qd.emitters import ESEmitters, IsoLineEmitter

    name = algo_cfg["name"]
    n, b, sigma0 = int(qd_cfg["n_emitters"]), int(qd_cfg["batch_size"]), float(qd_cfg["sigma0"])
    if name == "cma_mae":
        return ESEmitters(
            n,
            b,
            dim,
            sigma0,
            ranking="improvement",
            restart_rule=algo_cfg.get("restart_rule", "no_improvement"),
        )
    if name == "cma_es":
        return ESEmitters(n, b, dim, sigma0, ranking="objective", restart_rule="basic")
    if name == "map_elites":
        return IsoLineEmitter(
            n * b,
            dim,
            float(algo_cfg["initial_sigma"]),
            float(algo_cfg["iso_sigma"]),
            float(algo_cfg["line_sigma"]),
            int(algo_cfg["n_initial"]),
        )
    raise NcaQdError(f"unknown algorithm {name!r} (known: cma_mae, map_elites, cma_es, dsage)")


MAP_ELITES_ARCHIVES = ("auto", "elitist", "threshold")


def map_elites_archive(algo_cfg: Any, domain_cfg: Any) -> str:
    """MAP-Elites' optimisation archive, ``elitist`` or ``threshold``: ``algo.archive``, where
    ``auto`` is what the paper's code ran in the domain (a threshold archive, CMA-MAE's, in the
    warehouse and manufacturing domains; an elitist one for the maze)."""
    from nca_qd.errors import NcaQdError

    kind = algo_cfg.get("archive")
    if kind not in MAP_ELITES_ARCHIVES:
        raise NcaQdError(f"algo.archive must be one of {', '.join(MAP_ELITES_ARCHIVES)}, got {kind!r}")
    if kind == "auto":
        return "elitist" if str(domain_cfg["name"]) == "maze" else "threshold"
    return str(kind)


def archive_spec(algo_cfg: Any, domain_cfg: Any, qd_cfg: Any) -> ArchiveSpec:
    """CMA-MAE, and MAP-Elites with a threshold archive (:func:`map_elites_archive`), use the
    configured learning rate and threshold_min; the other baselines a plain archive."""
    meas = domain_cfg["measures"]
    name = algo_cfg["name"]
    soft = name == "cma_mae" or (
        name == "map_elites" and map_elites_archive(algo_cfg, domain_cfg) == "threshold"
    )
    return ArchiveSpec(
        cells=[int(c) for c in meas["cells"]],
        ranges=[[float(r[0]), float(r[1])] for r in meas["ranges"]],
        learning_rate=float(qd_cfg["archive"]["learning_rate"]) if soft else 1.0,
        threshold_min=float(qd_cfg["archive"]["threshold_min"]) if soft else -float("inf"),
        qd_offset=float(domain_cfg["objective_range"][0]),
    )


def archive_fields_to_arrays(fields: Mapping[str, Any]) -> dict[str, np.ndarray]:
    """Dense numpy arrays of a repertoire's fields by name (a dense msgpack checkpoint of an
    earlier version): genotypes, objective, measures, centroids and, if present, thresholds."""
    out = {
        "genotypes": np.asarray(fields["genotypes"]),
        "objective": np.asarray(fields["fitnesses"])[:, 0],
        "measures": np.asarray(fields["descriptors"]),
        "centroids": np.asarray(fields["centroids"]),
    }
    if "thresholds" in fields and np.ndim(fields["thresholds"]) == 1:
        out["thresholds"] = np.asarray(fields["thresholds"])
    return out
