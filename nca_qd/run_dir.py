"""A run directory as other tools read it: its file names, configuration and archives.

:class:`nca_qd.experiment.Experiment` writes a run directory; the evaluation, the renderer, the
maze-transfer study and the notebooks only read one. They need no QD loop, no emitter and no
domain for that: :func:`load_archive` reads a finished run's ``archive_<which>.npz`` or, while
the run is going on (or on a fresh clone that has only the portable snapshot), the archive
inside its checkpoint.
"""

from __future__ import annotations

import logging
from pathlib import Path
from typing import Any

import numpy as np
from omegaconf import DictConfig, OmegaConf

from nca_qd.errors import NcaQdError
from nca_qd.qd import archive_io, checkpoint
from nca_qd.qd.loop import archive_fields_to_arrays
from nca_qd.sim.free_flow import CONGESTED_MODEL_V3

log = logging.getLogger("nca_qd.run")

CONFIG_FILE, METRICS_FILE, CHECKPOINT_FILE = "config.yaml", "metrics.csv", "checkpoint.npz"
LEGACY_CHECKPOINT_FILE = "checkpoint.msgpack"  # dense msgpack of earlier versions
SNAPSHOT_FILE = "snapshot.npz"  # portable: the state a fresh clone resumes from
ELITES_FILE = "elites.npz"  # the result archive's figures and its best generators (archive_io)

# Settings added after runs had been saved, each with the value that a saved configuration
# without it ran with. The YAML holds the one default of new runs; :func:`migrate` gives an old
# run directory its old behaviour explicitly, so a resumed or re-read run decides as it did.
LEGACY_SETTINGS: dict[str, Any] = {
    # the screen's prediction before the free-flow estimate (2026-11-26): screened x screen_scale
    "eval.screen_estimate": "scaled",
    # the congested-layout share of the free-flow estimate, fitted against exact simulator
    # version 3, before the version-4 refit
    "eval.screen_congested": list(CONGESTED_MODEL_V3),
    # the exact planner's start rules before run.yaml named them (2026-11-29): RHCR's own
    "eval.prioritize_start": True,
    "eval.starts": "random",
    # the exact planner before PIBT joined the core (2026-11-29): RHCR
    "eval.planner": "rhcr",
}


def load_run_config(run_dir: str | Path) -> DictConfig:
    """The saved configuration of a run directory (for ``resume=``)."""
    path = Path(run_dir) / CONFIG_FILE
    if not Path(run_dir).is_dir():
        raise NcaQdError(f"run directory {run_dir} does not exist")
    if not path.is_file():
        raise NcaQdError(f"{run_dir} is not a run directory ({CONFIG_FILE} missing)")
    cfg = OmegaConf.load(path)
    filled = migrate(cfg)  # type: ignore[arg-type]
    if filled:
        log.info("%s: saved before %s existed; reading them as the run used them", run_dir, ", ".join(filled))
    return cfg  # type: ignore[return-value]


def migrate(cfg: DictConfig) -> list[str]:
    """Fill in the :data:`LEGACY_SETTINGS` a saved run configuration lacks (in place, only within
    blocks it has), and a MAP-Elites run's archive and initial spread; returns the keys filled.
    The legacy settings are all the multi-agent scorer's (screen, exact planner): a maze run's
    ``eval`` block (workers, retries) gets none."""
    filled: list[str] = []
    algo = OmegaConf.select(cfg, "algo")
    if isinstance(algo, DictConfig) and algo.get("name") == "map_elites":
        # MAP-Elites before it was set as the paper's code ran it (2026-12-01): an elitist
        # archive, its first solutions drawn from N(0, qd.sigma0^2)
        for key, value in (("archive", "elitist"), ("initial_sigma", OmegaConf.select(cfg, "qd.sigma0"))):
            if key not in algo:
                algo[key] = value
                filled.append(f"algo.{key}")
    if OmegaConf.select(cfg, "domain.name") == "maze":
        return filled
    for dotted, value in LEGACY_SETTINGS.items():
        block, key = dotted.rsplit(".", 1)
        parent = OmegaConf.select(cfg, block)
        if isinstance(parent, DictConfig) and key not in parent:
            parent[key] = value
            filled.append(dotted)
    return filled


def select_elites(objective: np.ndarray, n: int) -> np.ndarray:
    """Cells of up to ``n`` elites: the best objective first; when more than ``n`` share the
    best value (the maze's binary objective), ``n`` of them spread evenly over the archive."""
    occ = np.flatnonzero(np.isfinite(objective))
    if occ.size == 0:
        return occ
    order = occ[np.lexsort((occ, -objective[occ]))]
    top = order[objective[order] == objective[order[0]]]
    if top.size >= n:
        return top[np.linspace(0, top.size - 1, n).round().astype(int)]
    return order[:n]


def _why_no_archive(run_dir: str | Path) -> str:
    """What a run directory without an archive most likely is: a run before its first iteration,
    or one whose archive was not kept (shipped runs of some studies keep their config, metrics
    and pictures only)."""
    metrics = Path(run_dir) / METRICS_FILE
    lines = metrics.read_text().splitlines()[1:] if metrics.is_file() else []
    done = [ln for ln in lines if ln.strip()]
    if not done:
        return "has the run finished an iteration yet?"
    return (
        f"its {METRICS_FILE} records {len(done)} iterations, so its archive was not kept here: "
        f"re-run it from its {CONFIG_FILE} to rebuild it"
    )


def load_archive(run_dir: str | Path, which: str = "result") -> dict[str, Any]:
    """A run's archive as per-cell arrays (:func:`nca_qd.qd.archive_io.archive_view`:
    ``objective``, ``measures``, ``thresholds``, ``centroids`` and ``genotypes`` indexed by cell).

    A finished run has ``archive_<which>.npz``; a run still in progress (or interrupted) has
    only its checkpoint, whose archive is read instead — so a long search can be evaluated,
    rendered or explored while it goes on, without stopping it. A run shipped without its
    archives or snapshot (the maze table's) has its result archive's elites record
    (``elites.npz``): every elite's figures, the parameters of its best few only."""
    path = Path(run_dir) / f"archive_{which}.npz"
    if path.is_file():
        return archive_io.read_archive(path)
    ckpt = Path(run_dir) / CHECKPOINT_FILE
    if not ckpt.is_file() and (Path(run_dir) / SNAPSHOT_FILE).is_file():
        ckpt = Path(run_dir) / SNAPSHOT_FILE
    legacy = Path(run_dir) / LEGACY_CHECKPOINT_FILE
    record = Path(run_dir) / ELITES_FILE
    if not ckpt.is_file() and not legacy.is_file() and which == "result" and record.is_file():
        log.info("%s: result archive read from %s (generators of its best elites only)", run_dir, ELITES_FILE)
        return archive_io.read_archive(record)
    if not ckpt.is_file() and not legacy.is_file():
        raise NcaQdError(f"{path} not found and no {CHECKPOINT_FILE} beside it ({_why_no_archive(run_dir)})")
    archive, iteration = archive_from_checkpoint(ckpt if ckpt.is_file() else legacy, which)
    source = ckpt if ckpt.is_file() else legacy
    log.info("%s: %s archive read from %s (iteration %d)", run_dir, which, source.name, iteration)
    return archive


def archives_held(run_dir: str | Path) -> tuple[str, ...]:
    """The archives :func:`load_archive` can read in ``run_dir``: both, unless the run holds
    only its elites record (the result archive's figures and best generators)."""
    d = Path(run_dir)
    names = ("archive_opt.npz", CHECKPOINT_FILE, SNAPSHOT_FILE, LEGACY_CHECKPOINT_FILE)
    whole = any((d / n).is_file() for n in names)
    return ("result", "opt") if whole or not (d / ELITES_FILE).is_file() else ("result",)


def archive_from_checkpoint(path: str | Path, which: str = "result") -> tuple[dict[str, Any], int]:
    """The ``which`` archive of a checkpoint as :func:`load_archive` gives it, and the
    checkpoint's iteration. Read without a template (no emitter or loop is built)."""
    path = Path(path)
    if path.suffix == ".npz":
        arrays, meta = checkpoint.read_checkpoint(path)
        grid = arrays["grid_cells"].tolist(), arrays["grid_ranges"].tolist()
        return (
            archive_io.archive_view(checkpoint.archive_from_arrays(arrays, which), *grid),
            int(meta["iteration"]),
        )
    from flax import serialization

    try:  # a dense msgpack checkpoint of an earlier version
        tree = serialization.msgpack_restore(path.read_bytes())
        state = tree["state"]
        arch = state[{"result": "res_archive", "opt": "opt_archive"}[which]]
        return archive_fields_to_arrays(arch), int(np.asarray(state["iteration"]))
    except (ValueError, KeyError, TypeError, IndexError) as exc:
        raise NcaQdError(f"{path}: not a readable checkpoint ({exc})") from None
