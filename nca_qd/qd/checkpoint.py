"""Sparse checkpoints: a QD state stored by what it holds, not by the size of its grid.

A dense QD state is mostly empty space: both archives hold ``cells x d`` parameters (41,472 x
1,730 float32 = 287 MB each for the maze, whatever the coverage) and every CMA-ES emitter a
``d x d`` covariance plus its ``d x d`` eigenbasis. A checkpoint here holds

* **archives as their elites**: for each occupied cell its index, objective, measures and
  threshold, exactly, and its parameters;
* **parameters by their role**: the result archive's elites are the product of the search and
  stay float32, bit for bit. An elite of the optimisation archive is the same solution as the
  result archive's elite of its cell more often than not (then only a flag is stored); the
  others serve only as restart points of the emitters and are stored at ``restart_dtype``
  (int8 with a per-row offset and scale: error at most 1/510 of the row's range, RMS ~0.3 %
  of it, a few per cent of the step size a restarted emitter samples with; float16 and
  float32 on request). ``exact_elites=n``
  (portable snapshots) keeps only the ``n`` best result elites float32 and stores the other
  result elites at ``restart_dtype`` too;
* **emitters as compact as they allow** (:meth:`ESEmitters.compact_state`): each CMA-ES
  instance's mean, step size, evolution paths and counters exactly, its covariance as the
  diagonal plus the ``covariance_rank`` leading eigenpairs of the off-diagonal part when what
  that leaves out, ``||C - approximation||_F / mean(diag C)``, is at most
  ``covariance_tolerance`` (0.1: a KL divergence of at most ~0.0025 nats between the sampling
  distributions), in full otherwise. At d ~ 2,000 CMA-ES's covariance learning rates are ~1e-6
  per generation, so ``C`` stays that close to diagonal for hundreds of generations; at
  d = 100 it does not, and is stored in full (``benchmarks/bench_checkpoint.py`` measures
  both). The cached eigenbasis ``B, D`` is not stored but recomputed from the matrix it
  factors, ``B D^2 B^T`` (stored the same compact way): CMA-ES refreshes it lazily (every ~230
  generations at d ~ 2,000), and recomputing it from the current ``C`` instead would make a
  resumed search sample from another distribution than the uninterrupted one.

``exact=True`` stores everything bit for bit (full covariance and eigenbasis, float32
parameters): a resumed run then replays the uninterrupted one exactly. The default policy
resumes to the same search statistically (tests/test_checkpoint.py checks both).

The file is one ``.npz`` written atomically; ``meta`` (JSON) names the format version, the
counters, the policy and whatever the caller adds (e.g. the simulator's version).
"""

from __future__ import annotations

import io as _io
import json
import logging
import zipfile
from collections.abc import Mapping
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from nca_qd.errors import NcaQdError, require_bool
from nca_qd.interfaces import CompactEmitter
from nca_qd.io import atomic_write_bytes
from nca_qd.qd.archive import ThresholdRepertoire, grid_cell_indices

log = logging.getLogger(__name__)

FORMAT = "nca-qd sparse checkpoint"
FORMAT_VERSION = 1


@dataclass(frozen=True)
class CheckpointPolicy:
    """What a checkpoint stores exactly and what it compresses (see module docstring)."""

    exact: bool = False
    restart_dtype: str = "int8"
    covariance_rank: int = 8
    covariance_tolerance: float = 0.1
    exact_elites: int | None = None  # None: every result elite float32

    def __post_init__(self):
        require_bool("checkpoint exact", self.exact)
        if self.restart_dtype not in ("int8", "float16", "float32"):
            raise NcaQdError(
                f"checkpoint restart_dtype must be int8, float16 or float32, got {self.restart_dtype!r}"
            )
        if not isinstance(self.covariance_rank, int) or self.covariance_rank < 0:
            raise NcaQdError(
                f"checkpoint covariance_rank must be a non-negative integer, got {self.covariance_rank!r}"
            )
        if (
            isinstance(self.covariance_tolerance, bool)
            or not isinstance(self.covariance_tolerance, (int, float))
            or not self.covariance_tolerance >= 0
        ):
            raise NcaQdError(
                f"checkpoint covariance_tolerance must be a number >= 0, got {self.covariance_tolerance!r}"
            )
        if self.exact_elites is not None and (
            not isinstance(self.exact_elites, int) or self.exact_elites < 0
        ):
            raise NcaQdError(
                f"checkpoint exact_elites must be a non-negative integer or null, got {self.exact_elites!r}"
            )

    @classmethod
    def from_config(cls, cfg: Mapping[str, Any] | None) -> CheckpointPolicy:
        cfg = dict(cfg or {})
        unknown = set(cfg) - {
            "exact",
            "restart_dtype",
            "covariance_rank",
            "covariance_tolerance",
            "exact_elites",
        }
        if unknown:
            raise NcaQdError(f"unknown checkpoint setting(s): {', '.join(sorted(unknown))}")
        return cls(**cfg)


# --- archives ------------------------------------------------------------------------------
def archive_elites(archive: ThresholdRepertoire) -> dict[str, np.ndarray]:
    """The occupied cells of an archive: ``cells``, ``objective``, ``measures``, ``thresholds``
    and ``genotypes`` (float32, one row per occupied cell)."""
    f = np.asarray(archive.fitnesses)[:, 0]
    cells = np.flatnonzero(f > -np.inf).astype(np.int32)
    return {
        "cells": cells,
        "objective": f[cells].astype(np.float32),
        "measures": np.asarray(archive.descriptors)[cells].astype(np.float32),
        "thresholds": np.asarray(archive.thresholds)[cells].astype(np.float32),
        "genotypes": np.asarray(archive.genotypes)[cells].astype(np.float32),
    }


def _restore_archive(
    template: ThresholdRepertoire,
    cells: np.ndarray,
    objective: np.ndarray,
    measures: np.ndarray,
    thresholds: np.ndarray,
    genotypes: np.ndarray,
) -> ThresholdRepertoire:
    n, d = template.genotypes.shape
    m = template.descriptors.shape[1]
    if cells.size and (cells.min() < 0 or cells.max() >= n):
        raise NcaQdError(f"checkpoint holds cell {int(cells.max())}, the archive has {n} cells")
    if genotypes.shape != (cells.size, d) or measures.shape != (cells.size, m):
        raise NcaQdError(
            f"checkpoint holds {genotypes.shape[1:]} parameters and {measures.shape[1:]} "
            f"measures per elite; this configuration has ({d},) and ({m},)"
        )
    cells, objective, measures, thresholds, genotypes = _rebin(
        template, cells, objective, measures, thresholds, genotypes
    )
    g = np.zeros((n, d), np.float32)
    g[cells] = genotypes
    f = np.full((n, 1), -np.inf, np.float32)
    f[cells, 0] = objective
    desc = np.zeros((n, m), np.float32)
    desc[cells] = measures
    thr = np.asarray(template.thresholds).copy()
    thr[cells] = thresholds
    return template.replace(
        genotypes=jnp.asarray(g),
        fitnesses=jnp.asarray(f),
        descriptors=jnp.asarray(desc),
        thresholds=jnp.asarray(thr),
    )


def _rebin(
    template: ThresholdRepertoire,
    cells: np.ndarray,
    objective: np.ndarray,
    measures: np.ndarray,
    thresholds: np.ndarray,
    genotypes: np.ndarray,
) -> tuple[np.ndarray, ...]:
    """Elites moved to the cells their measures map to today.

    Checkpoints written before :func:`nca_qd.qd.archive.grid_cell_indices` stopped rounding
    integer measures into the cell below hold some elites one cell low; each moves, with its
    threshold, to its own cell (where two meet, the higher objective stays)."""
    if not cells.size or not template.grid_cells:
        return cells, objective, measures, thresholds, genotypes
    now = np.asarray(
        grid_cell_indices(jnp.asarray(measures, jnp.float32), template.grid_cells, template.grid_ranges)
    ).astype(cells.dtype)
    if np.array_equal(now, cells):
        return cells, objective, measures, thresholds, genotypes
    order = np.lexsort((-objective, now))  # by cell, best first
    keep = order[np.r_[True, now[order][1:] != now[order][:-1]]]
    log.warning(
        "checkpoint: %d of %d elites re-binned to the cells their measures map to (%d dropped where two met)",
        int((now != cells).sum()),
        cells.size,
        cells.size - keep.size,
    )
    return now[keep], objective[keep], measures[keep], thresholds[keep], genotypes[keep]


def _store_params(name: str, rows: np.ndarray, dtype: str) -> dict[str, np.ndarray]:
    """Rows stored at ``dtype`` as arrays named ``name*``: float32 as is; float16 (float32
    where float16 would overflow); int8 with a per-row offset and scale (error <= range/510)."""
    rows = np.asarray(rows, np.float32)
    if dtype == "float16":
        low = rows.astype(np.float16)
        return {name: low if np.all(np.isfinite(low)) else rows}
    if dtype == "int8" and rows.size:
        lo, hi = rows.min(axis=1, keepdims=True), rows.max(axis=1, keepdims=True)
        scale = np.where(hi > lo, (hi - lo) / 255.0, 1.0).astype(np.float32)
        q = np.clip(np.rint((rows - lo) / scale) - 128, -128, 127).astype(np.int8)
        return {name: q, name + "_offset": lo[:, 0], name + "_scale": scale[:, 0]}
    return {name: rows}


def _load_params(arrays: Mapping[str, np.ndarray], name: str) -> np.ndarray:
    """Inverse of :func:`_store_params`, as float32."""
    rows = arrays[name]
    if rows.dtype == np.int8:
        offset, scale = arrays[name + "_offset"], arrays[name + "_scale"]
        return ((rows.astype(np.float32) + 128.0) * scale[:, None] + offset[:, None]).astype(np.float32)
    return rows.astype(np.float32)


def encode_archives(
    res: ThresholdRepertoire, opt: ThresholdRepertoire, policy: CheckpointPolicy
) -> dict[str, np.ndarray]:
    """Both archives as arrays named ``res_*`` and ``opt_*`` (see module docstring)."""
    out: dict[str, np.ndarray] = {}
    r, o = archive_elites(res), archive_elites(opt)
    restart = "float32" if policy.exact else policy.restart_dtype
    # Result archive: float32 unless exact_elites asks to keep only the best ones exact.
    keep = np.ones(r["cells"].size, bool)
    if policy.exact_elites is not None and not policy.exact:
        keep[:] = False
        best = np.lexsort((r["cells"], -r["objective"]))[: policy.exact_elites]
        keep[best] = True
    out.update({f"res_{k}": v for k, v in r.items() if k != "genotypes"})
    out["res_exact"] = keep
    out["res_genotypes"] = r["genotypes"][keep]
    out.update(_store_params("res_restart_genotypes", r["genotypes"][~keep], restart))
    # Optimisation archive: a flag where its elite is the result archive's elite of that cell.
    res_row = np.full(np.asarray(res.fitnesses).shape[0], -1, np.int64)
    res_row[r["cells"]] = np.arange(r["cells"].size)
    rows = res_row[o["cells"]]
    shared = rows >= 0
    shared[shared] = np.all(r["genotypes"][rows[shared]] == o["genotypes"][shared], axis=1)
    out.update({f"opt_{k}": v for k, v in o.items() if k != "genotypes"})
    out["opt_shared"] = shared
    out.update(_store_params("opt_genotypes", o["genotypes"][~shared], restart))
    out["grid_cells"] = np.asarray(res.grid_cells, np.int64)
    out["grid_ranges"] = np.asarray(res.grid_ranges, np.float64)
    return out


def decode_archives(
    arrays: Mapping[str, np.ndarray], res_template: ThresholdRepertoire, opt_template: ThresholdRepertoire
) -> tuple[ThresholdRepertoire, ThresholdRepertoire]:
    """Inverse of :func:`encode_archives` into empty archives of this configuration."""
    d = res_template.genotypes.shape[1]
    if tuple(arrays["grid_cells"].tolist()) != tuple(res_template.grid_cells):
        raise NcaQdError(
            f"checkpoint's archive grid is {tuple(arrays['grid_cells'].tolist())}, "
            f"this configuration's {tuple(res_template.grid_cells)}"
        )
    if arrays["res_genotypes"].shape[1:] != (d,):
        raise NcaQdError(
            f"checkpoint holds {arrays['res_genotypes'].shape[1]} parameters per "
            f"elite; this configuration has {d}"
        )
    archives = []
    for which, template in (("result", res_template), ("opt", opt_template)):
        e = archive_from_arrays(arrays, which)
        archives.append(
            _restore_archive(
                template, e["cells"], e["objective"], e["measures"], e["thresholds"], e["genotypes"]
            )
        )
    return archives[0], archives[1]


# --- emitters and other state --------------------------------------------------------------
def _leaves(tree: Any) -> list[tuple[str, Any]]:
    return [(jax.tree_util.keystr(p), v) for p, v in jax.tree_util.tree_flatten_with_path(tree)[0]]


def encode_tree(prefix: str, tree: Any) -> dict[str, np.ndarray]:
    """Every leaf of a pytree, exactly, named ``prefix + keystr(path)``."""
    return {prefix + name: np.asarray(v) for name, v in _leaves(tree)}


def decode_tree(prefix: str, arrays: Mapping[str, np.ndarray], template: Any) -> Any:
    """Inverse of :func:`encode_tree` into the structure (and dtypes) of ``template``."""
    paths, treedef = jax.tree_util.tree_flatten_with_path(template)
    leaves = []
    for path, ref in paths:
        name = prefix + jax.tree_util.keystr(path)
        if name not in arrays:
            raise NcaQdError(f"checkpoint lacks {name} (written by another algorithm or version)")
        value = np.asarray(arrays[name])
        if value.shape != np.shape(ref):
            raise NcaQdError(
                f"checkpoint's {name} has shape {value.shape}, this configuration needs {np.shape(ref)}"
            )
        leaves.append(jnp.asarray(value, dtype=jnp.asarray(ref).dtype))
    return jax.tree_util.tree_unflatten(treedef, leaves)


# --- whole state ---------------------------------------------------------------------------
def encode_state(state: Any, emitter: Any, policy: CheckpointPolicy) -> tuple[dict[str, np.ndarray], dict]:
    """A :class:`~nca_qd.qd.loop.QDState` as named arrays, plus what the encoding measured
    (e.g. the covariance left out)."""
    arrays = encode_archives(state.res_archive, state.opt_archive, policy)
    info: dict[str, Any] = {}
    if isinstance(emitter, CompactEmitter) and not policy.exact:
        em, info = emitter.compact_state(
            state.emitter_state, policy.covariance_rank, policy.covariance_tolerance
        )
        arrays.update({"emitter" + k: v for k, v in em.items()})
    else:
        arrays.update(encode_tree("emitter", state.emitter_state))
    arrays["key"] = np.asarray(
        jax.random.key_data(state.key) if jnp.issubdtype(state.key.dtype, jax.dtypes.prng_key) else state.key
    )
    arrays["iteration"] = np.asarray(state.iteration)
    arrays["evaluations"] = np.asarray(state.evaluations)
    return arrays, info


def decode_state(arrays: Mapping[str, np.ndarray], template: Any, emitter: Any, exact: bool) -> Any:
    """Inverse of :func:`encode_state` into the structure of ``template`` (an initial state)."""
    res, opt = decode_archives(arrays, template.res_archive, template.opt_archive)
    if isinstance(emitter, CompactEmitter) and not exact:
        em = {k[len("emitter") :]: v for k, v in arrays.items() if k.startswith("emitter")}
        emitter_state = emitter.expand_state(em, template.emitter_state)
    else:
        emitter_state = decode_tree("emitter", arrays, template.emitter_state)
    return template.replace(
        res_archive=res,
        opt_archive=opt,
        emitter_state=emitter_state,
        key=jnp.asarray(arrays["key"], dtype=template.key.dtype),
        iteration=jnp.asarray(arrays["iteration"], dtype=template.iteration.dtype),
        evaluations=jnp.asarray(arrays["evaluations"], dtype=template.evaluations.dtype),
    )


def save_checkpoint(
    path: str | Path,
    state: Any,
    emitter: Any,
    policy: CheckpointPolicy,
    meta: Mapping[str, Any] | None = None,
    compress: bool = False,
) -> dict:
    """Write ``state`` to ``path`` atomically; returns the meta dict written."""
    arrays, info = encode_state(state, emitter, policy)
    full_meta = {
        "format": FORMAT,
        "version": FORMAT_VERSION,
        "iteration": int(state.iteration),
        "evaluations": int(state.evaluations),
        "policy": asdict(policy),
        "encoding": info,
        **dict(meta or {}),
    }
    arrays["meta"] = np.asarray(json.dumps(full_meta))
    buf = _io.BytesIO()
    (np.savez_compressed if compress else np.savez)(buf, **arrays)
    atomic_write_bytes(path, buf.getvalue())
    return full_meta


def read_checkpoint(path: str | Path) -> tuple[dict[str, np.ndarray], dict]:
    """The arrays and meta of a checkpoint file; one clear error if it is not one."""
    try:
        with np.load(path, allow_pickle=False) as data:
            arrays = {k: data[k] for k in data.files}
        meta = json.loads(str(arrays.pop("meta")))
    except (OSError, ValueError, KeyError, zipfile.BadZipFile, json.JSONDecodeError) as exc:
        raise NcaQdError(f"{path}: not a readable checkpoint ({exc})") from None
    if meta.get("format") != FORMAT:
        raise NcaQdError(f"{path}: not an nca-qd checkpoint")
    if int(meta.get("version", 0)) > FORMAT_VERSION:
        raise NcaQdError(
            f"{path}: checkpoint format {meta.get('version')} is newer than this "
            f"nca-qd reads ({FORMAT_VERSION}); update the package"
        )
    return arrays, meta


def load_checkpoint(path: str | Path, template: Any, emitter: Any) -> tuple[Any, dict]:
    """The state stored at ``path``, restored into the structure of ``template``."""
    arrays, meta = read_checkpoint(path)
    try:
        state = decode_state(arrays, template, emitter, bool(meta["policy"]["exact"]))
    except NcaQdError as exc:
        raise NcaQdError(f"{path}: checkpoint does not match this configuration ({exc})") from None
    except KeyError as exc:
        raise NcaQdError(f"{path}: checkpoint lacks {exc}") from None
    return state, meta


def archive_from_arrays(arrays: Mapping[str, np.ndarray], which: str) -> dict[str, np.ndarray]:
    """The ``which`` ("result" | "opt") archive of a checkpoint's arrays as sparse archive
    arrays (``cells``, ``objective``, ``measures``, ``thresholds``, ``genotypes``), without
    building any loop or emitter. Optimisation-archive rows that serve only as restart points
    come back at float32 from their stored precision."""
    r_cells = arrays["res_cells"]
    keep = arrays["res_exact"].astype(bool)
    d = arrays["res_genotypes"].shape[1]
    r_g = np.zeros((r_cells.size, d), np.float32)
    r_g[keep] = arrays["res_genotypes"]
    r_g[~keep] = _load_params(arrays, "res_restart_genotypes")
    p = "res" if which == "result" else "opt"
    out = {k: arrays[f"{p}_{k}"] for k in ("cells", "objective", "measures", "thresholds")}
    if which == "result":
        out["genotypes"] = r_g
    else:
        shared = arrays["opt_shared"].astype(bool)
        row_of = np.full(int(np.prod(arrays["grid_cells"])), -1, np.int64)
        row_of[r_cells] = np.arange(r_cells.size)
        g = np.zeros((out["cells"].size, d), np.float32)
        g[shared] = r_g[row_of[out["cells"][shared]]]
        g[~shared] = _load_params(arrays, "opt_genotypes")
        out["genotypes"] = g
    return out
