"""DSAGE's outer loop: train the surrogate, search on it, evaluate a sample for real.

Deep Surrogate Assisted Generation of Environments (Bhatt et al. 2022; for warehouses Zhang et
al. 2023), the baseline of the NCA paper: a direct search over tile layouts of the training size
S, no generator. One outer iteration:

1. train the surrogate (:mod:`nca_qd.qd.dsage.surrogate`) on every real evaluation so far;
2. run MAP-Elites on the surrogate's predictions for ``inner.iterations`` batches from an empty
   *surrogate archive* (:mod:`nca_qd.qd.dsage.tiles`), ranked by the predicted f_opt;
3. downsample that archive to a coarse grid (one random elite per block) and evaluate those
   layouts with the domain's real scorer (repair and simulation, or the maze agent);
4. add them to the result archive (f_res) and the optimisation archive (f_opt; what the
   surrogate learns) and to the training data.

The first iteration evaluates ``initial_solutions`` random layouts instead. The run ends when
``qd.n_evals`` real evaluations are spent (the last batch is cut to fit).

:class:`DSAGELoop` offers what :class:`~nca_qd.qd.loop.QDLoop` offers (``init``, ``step``,
``context``), so :class:`~nca_qd.experiment.Experiment` runs, checkpoints and resumes it the same
way: its state is a :class:`~nca_qd.qd.loop.QDState` whose ``emitter_state`` holds the surrogate's
weights, its optimiser state and the number of training rows. The training data itself (every
real evaluation: layout, f_opt, measures, ancillary map) grows on the host and is written beside
the checkpoint as ``dsage_data.npz`` just before it (like the MAPF scorer's memo); a resume cuts
it back to the checkpoint's row count, so a kill between the two writes loses nothing.
"""

from __future__ import annotations

import math
import time
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import chex
import flax.struct
import jax
import jax.numpy as jnp
import numpy as np

from nca_qd.errors import NcaQdError
from nca_qd.interfaces import EvalBatch, ScoringContext
from nca_qd.io import save_npz
from nca_qd.qd.archive import ThresholdRepertoire
from nca_qd.qd.dsage.surrogate import Surrogate, SurrogateConfig
from nca_qd.qd.dsage.tiles import downsample, make_inner_loop, random_layouts
from nca_qd.qd.loop import ArchiveSpec, QDState, add_to_archives, scoring_context, step_metrics

DSAGE_METRICS = (
    "n_real",
    "surrogate_loss",
    "surrogate_coverage",
    "predicted_objective_error",
    "predicted_measure_error",
    "train_seconds",
    "inner_seconds",
    "eval_seconds",
)


DATA_FILE = "dsage_data.npz"


class DSAGEData(flax.struct.PyTreeNode):
    """The surrogate's weights and optimiser state, and how many training rows exist."""

    params: Any
    opt_state: Any
    count: jax.Array


class DSAGELoop:
    """DSAGE over one domain's layouts of the training size (see module docstring).

    ``algo_cfg``: ``initial_solutions``, ``inner`` (``iterations``, ``emitters``, ``batch_size``
    per emitter, ``initial_population``, ``mutation_k``), ``downsample`` (coarse cells per
    measure),
    ``surrogate`` (:class:`SurrogateConfig` fields); ``objective_range`` the domain's.
    """

    metric_names = DSAGE_METRICS

    def __init__(
        self,
        objective: Any,
        shape: tuple[int, int],
        n_tiles: int,
        spec: ArchiveSpec,
        objective_range: tuple[float, float],
        n_evals: int,
        algo_cfg: Mapping[str, Any],
    ):
        self.objective, self.spec = objective, spec
        self.shape, self.n_tiles = (int(shape[0]), int(shape[1])), int(n_tiles)
        self.dim = self.shape[0] * self.shape[1]
        self.n_evals = int(n_evals)
        inner = dict(algo_cfg["inner"])
        self.initial_solutions = int(algo_cfg["initial_solutions"])
        self.coarse = [int(c) for c in algo_cfg["downsample"]]
        if len(self.coarse) != len(spec.cells) or any(
            c < 1 or f % c for c, f in zip(self.coarse, spec.cells)
        ):
            raise NcaQdError(
                f"algo.downsample must give one divisor of each archive dimension {list(spec.cells)}, "
                f"got {self.coarse}"
            )
        for name in ("iterations", "emitters", "batch_size", "initial_population", "mutation_k"):
            if not isinstance(inner.get(name), int) or isinstance(inner[name], bool) or inner[name] < 1:
                raise NcaQdError(f"algo.inner.{name} must be a positive integer, got {inner.get(name)!r}")
        if inner["mutation_k"] > self.dim:
            raise NcaQdError(f"algo.inner.mutation_k must be at most {self.dim}, got {inner['mutation_k']}")
        if self.initial_solutions < 1:
            raise NcaQdError(f"algo.initial_solutions must be positive, got {self.initial_solutions}")
        self.surrogate_cfg = SurrogateConfig(**dict(algo_cfg.get("surrogate") or {}))
        lows = [float(objective_range[0])] + [float(r[0]) for r in spec.ranges]
        highs = [float(objective_range[1])] + [float(r[1]) for r in spec.ranges]
        self.surrogate = Surrogate(self.shape, self.n_tiles, lows, highs, self.surrogate_cfg)
        self.inner_iterations = int(inner["iterations"])
        self._inner = make_inner_loop(
            self.surrogate.predict,
            self.shape,
            self.n_tiles,
            spec.cells,
            spec.ranges,
            int(inner["iterations"]),
            int(inner["emitters"]),
            int(inner["batch_size"]),
            int(inner["initial_population"]),
            int(inner["mutation_k"]),
        )
        self._downsample = jax.jit(lambda a, k: downsample(a, k, self.coarse))
        # One padded batch size for every real evaluation: the archives' update (and a jitted
        # scorer) compile once.
        self.batch_size = max(self.initial_solutions, math.prod(self.coarse))
        self.data = self._empty_data()
        self.emitter = self  # what the checkpoint asks about the state's "emitter" part
        self._update = jax.jit(self._update_impl)

    # --- state ---------------------------------------------------------------------------
    def init(self, key: jax.Array) -> QDState:
        k_model, k_run = jax.random.split(key)
        params, opt_state = self.surrogate.init(k_model)
        data = DSAGEData(params=params, opt_state=opt_state, count=jnp.zeros((), jnp.int32))
        self.data = self._empty_data()
        return QDState(
            opt_archive=ThresholdRepertoire.create(self.dim, self.spec.cells, self.spec.ranges),
            res_archive=ThresholdRepertoire.create(self.dim, self.spec.cells, self.spec.ranges),
            emitter_state=data,
            key=k_run,
            iteration=jnp.zeros((), jnp.int32),
            evaluations=jnp.zeros((), jnp.int32),
        )

    def _empty_data(self) -> dict[str, np.ndarray]:
        h, w = self.shape
        return {
            "layouts": np.zeros((0, h, w), np.int8),
            "targets": np.zeros((0, 1 + len(self.spec.cells)), np.float32),
            "ancillary": np.zeros((0, h, w), np.float16),
        }

    def save_state(self, run_dir) -> None:
        """Write the training data (``dsage_data.npz``, atomically)."""
        save_npz(Path(run_dir) / DATA_FILE, self.data)

    def restore_state(self, run_dir, state: QDState) -> None:
        """Read the training data back, cut to the rows the checkpoint ``state`` counts."""
        path = Path(run_dir) / DATA_FILE
        count = int(state.emitter_state.count)
        if count == 0:
            self.data = self._empty_data()
            return
        try:
            with np.load(path) as f:
                data = {k: f[k][:count] for k in ("layouts", "targets", "ancillary")}
        except (OSError, KeyError, ValueError) as exc:
            raise NcaQdError(f"{path}: DSAGE's training data is missing or unreadable ({exc})") from None
        if data["layouts"].shape[0] < count or data["layouts"].shape[1:] != self.shape:
            raise NcaQdError(
                f"{path} holds {data['layouts'].shape[0]} rows of {data['layouts'].shape[1:]}; the "
                f"checkpoint needs {count} of {self.shape}"
            )
        self.data = data

    def finished(self, state: QDState) -> bool:
        return int(state.evaluations) >= self.n_evals

    def context(self, state: QDState) -> ScoringContext:
        return scoring_context(state, self.spec)

    # --- one outer iteration ---------------------------------------------------------------
    def _update_impl(self, state: QDState, sols, f_opt, f_res, measures, valid, result_valid, n_real):
        b = self.batch_size
        chex.assert_shape(sols, (b, self.dim))
        chex.assert_shape([f_opt, f_res, valid, result_valid], (b,))
        real = jnp.arange(b) < n_real
        opt_archive, res_archive, _, _, metrics = add_to_archives(
            state, sols, f_opt, f_res, measures, valid & real, result_valid & real, self.spec
        )
        data = state.emitter_state
        data = data.replace(count=data.count + jnp.sum(valid & real).astype(jnp.int32))
        new = state.replace(
            opt_archive=opt_archive,
            res_archive=res_archive,
            emitter_state=data,
            iteration=state.iteration + 1,
            evaluations=state.evaluations + n_real,
        )
        return new, metrics

    def step(self, state: QDState) -> tuple[QDState, dict[str, float], EvalBatch]:
        """One outer iteration (see module docstring); returns state, scalar metrics, evaluation."""
        t0 = time.perf_counter()
        key, k_init, k_train, k_inner, k_down, k_eval = jax.random.split(state.key, 6)
        state = state.replace(key=key)
        data = state.emitter_state
        extra = {name: float("nan") for name in DSAGE_METRICS}
        predicted = None
        if int(state.iteration) == 0:
            sols = np.asarray(random_layouts(k_init, self.initial_solutions, self.dim, self.n_tiles))
        else:
            t = time.perf_counter()
            seed = int(jax.random.randint(k_train, (), 0, 2**31 - 1))
            params, opt_state, loss = self.surrogate.train(
                data.params,
                data.opt_state,
                self.data["layouts"],
                self.data["targets"],
                self.data["ancillary"],
                seed,
            )
            jax.block_until_ready(params)
            extra["train_seconds"] = time.perf_counter() - t
            extra["surrogate_loss"] = float(loss)
            state = state.replace(emitter_state=data.replace(params=params, opt_state=opt_state))
            t = time.perf_counter()
            inner = self._inner(params, k_inner)
            jax.block_until_ready(inner)
            genotypes, pred_obj, pred_meas, selected = jax.device_get(self._downsample(inner, k_down))
            extra["inner_seconds"] = time.perf_counter() - t
            extra["surrogate_coverage"] = float(jnp.mean(inner.occupied))
            sols = genotypes[selected]
            predicted = (pred_obj[selected], pred_meas[selected])
        remaining = self.n_evals - int(state.evaluations)
        sols = sols[:remaining]
        n_real = int(sols.shape[0])
        if n_real == 0:
            raise NcaQdError("DSAGE: the surrogate archive is empty; nothing to evaluate")
        t = time.perf_counter()
        ev = self._evaluate(sols, k_eval, state)
        jax.block_until_ready(ev.objective)
        extra["eval_seconds"] = time.perf_counter() - t
        extra["n_real"] = n_real
        if predicted is not None:
            obj_span = self.surrogate.span[0]
            meas_span = np.asarray(self.surrogate.span[1:])
            ok = np.asarray(ev.valid, bool)[:n_real]
            if ok.any():
                extra["predicted_objective_error"] = float(
                    np.mean(np.abs(predicted[0][:n_real][ok] - np.asarray(ev.objective)[:n_real][ok]))
                    / obj_span
                )
                extra["predicted_measure_error"] = float(
                    np.mean(
                        np.abs(predicted[1][:n_real][ok] - np.asarray(ev.measures)[:n_real][ok]) / meas_span
                    )
                )
        self._append_data(sols, ev, n_real)
        state, metrics = self._update(state, *self._pad(sols, ev, n_real), jnp.asarray(n_real, jnp.int32))
        return state, step_metrics(metrics, ev, state, t0, extra), ev

    def _evaluate(self, sols: np.ndarray, key: jax.Array, state: QDState) -> EvalBatch:
        """The real scorer on ``sols``. A jitted scorer gets the batch padded with copies of its
        first row to a power of two (at least 32, at most the largest batch): a few compiles,
        and padding costs at most as many evaluations as the batch holds."""
        n = sols.shape[0]
        if not getattr(self.objective, "metric_names", ()):
            size = min(self.batch_size, max(32, 1 << (n - 1).bit_length()))
            padded = np.concatenate([sols, np.repeat(sols[:1], size - n, axis=0)])
            ev = self.objective(jnp.asarray(padded), key, self.context(state))
        else:
            ev = self.objective(jnp.asarray(sols), key, self.context(state))
        return ev

    def _append_data(self, sols: np.ndarray, ev: EvalBatch, n: int) -> None:
        """The valid evaluations become training rows (DSAGE drops failed ones)."""
        ok = np.asarray(ev.valid, bool)[:n]
        anc = ev.extras.get("ancillary")
        if anc is None:
            if self.surrogate_cfg.use_ancillary:
                raise NcaQdError(
                    "DSAGE: this domain's scorer reports no ancillary map; "
                    "set algo.surrogate.use_ancillary=false"
                )
            anc = np.zeros((n, *self.shape), np.float32)
        new = {
            "layouts": np.rint(sols[:n][ok]).astype(np.int8).reshape(-1, *self.shape),
            "targets": np.concatenate(
                [np.asarray(ev.objective, np.float32)[:n, None], np.asarray(ev.measures, np.float32)[:n]],
                axis=1,
            )[ok],
            "ancillary": np.asarray(anc, np.float32)[:n][ok].astype(np.float16),
        }
        self.data = {k: np.concatenate([self.data[k], new[k]]) for k in new}

    def _pad(self, sols: np.ndarray, ev: EvalBatch, n: int):
        b = self.batch_size

        def pad(x, fill=0):
            x = np.asarray(x)[:n]
            return jnp.asarray(np.concatenate([x, np.full((b - n, *x.shape[1:]), fill, x.dtype)]))

        return (
            pad(sols.astype(np.float32)),
            pad(ev.objective),
            pad(ev.result_objective),
            pad(ev.measures),
            pad(np.asarray(ev.valid, bool), False),
            pad(np.asarray(ev.result_valid, bool), False),
        )
