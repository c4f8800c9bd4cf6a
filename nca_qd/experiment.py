"""A QD run on disk: the loop that writes configuration, metrics, checkpoints and archives.

Reading a run directory is :mod:`nca_qd.run_dir`; its pictures are :mod:`nca_qd.run_pictures`.

A run directory holds

* ``config.yaml``: the resolved configuration (a resumed run reuses it);
* ``metrics.csv``: one row per iteration (result archive's ``qd_score``, ``coverage``,
  ``best_objective``; the optimisation archive's as ``opt_*``; ``evaluations``; ``step_seconds``,
  the iteration's step; ``wall_seconds``, the search's wall clock so far: steps, rows and
  checkpoints, not the time between legs);
* ``checkpoint.npz``: the QD state (archives as their elites, emitters, key, counters) in the
  sparse format of :mod:`nca_qd.qd.checkpoint`, written atomically after the first iteration
  that ends ``qd.checkpoint_seconds`` after the last one and every ``qd.checkpoint_every``
  iterations (either may be null), at the end and on Ctrl-C (``checkpoint.exact`` chooses
  a bit-exact or a compact emitter state); a ``checkpoint.msgpack`` of earlier versions
  (dense) still resumes, and is replaced by the first new checkpoint;
* ``snapshot.npz`` (``snapshot.enabled``; ``auto``, the default: for run directories under a
  ``results/`` folder): a portable copy of each checkpoint, small enough to commit (only the
  best ``snapshot.exact_elites`` result elites keep float32 parameters); a run whose
  ``checkpoint.npz`` is missing (a fresh clone) resumes from it;
* ``eval_memo.npz`` (warehouse, manufacturing): the repairs and exact runs already made,
  written just before each checkpoint (:mod:`nca_qd.scoring.memo`);
* ``archive_result.npz`` / ``archive_opt.npz``: both archives as their elites
  (:mod:`nca_qd.qd.archive_io`), written at the end (:func:`load_archive` reads a running
  run's checkpoint instead);
* ``elites.npz`` (``output.kept_elites`` > 0): the result archive's elites record
  (:func:`nca_qd.qd.archive_io.save_elites_record`: every elite's objective and measures, the
  parameters of the best ``output.kept_elites``), written with the archives — what a run ships
  when its archives and snapshot are too large to (the maze table's runs);
* pictures: ``archive_result.png``, ``archive_opt.png``, ``curves.png``, ``best_train.png`` and
  ``best_eval.png`` (the same generators at the training and the evaluation size) and, for
  domains with repair, ``best_train_repaired.png`` / ``best_eval_repaired.png``.

Everything is deterministic given ``seed``. With ``checkpoint.exact=true`` a resumed run replays
from its last checkpoint and ends where an uninterrupted run ends; the default compact
checkpoint resumes the same search up to the covariance it leaves out and the rounding of
restart points (tests/test_checkpoint.py).
"""

from __future__ import annotations

import csv
import logging
import math
import time
from collections.abc import Callable
from pathlib import Path

import jax
import numpy as np
from omegaconf import DictConfig, OmegaConf

from nca_qd.domains import Domain, make_domain
from nca_qd.errors import NcaQdError, require_bool
from nca_qd.io import atomic_write_text, load_pytree
from nca_qd.pipeline import make_generator, make_objective
from nca_qd.preload import preload
from nca_qd.qd import archive_io, checkpoint
from nca_qd.qd.loop import QDLoop, QDState, archive_spec, make_emitter
from nca_qd.run_dir import (  # re-exported: readers of a run directory used to find them here
    CHECKPOINT_FILE,
    CONFIG_FILE,
    ELITES_FILE,
    LEGACY_CHECKPOINT_FILE,
    METRICS_FILE,
    SNAPSHOT_FILE,
    archive_from_checkpoint,
    load_archive,
    load_run_config,
    select_elites,
)

log = logging.getLogger("nca_qd.run")

METRIC_COLUMNS = [
    "iteration",
    "evaluations",
    "qd_score",
    "coverage",
    "best_objective",
    "n_elites",
    "opt_qd_score",
    "opt_coverage",
    "opt_best_objective",
    "batch_best",
    "batch_added",
    "step_seconds",
    "wall_seconds",
]
# Config keys that belong to one invocation, not to the run: never saved in config.yaml.
INVOCATION_KEYS = ("allow_simulator_change", "leg_seconds")
# leg_seconds judges the next iteration by the longest of the last this many (of this leg's
# own once it has run one: a leg resumed on another machine must not be judged by the last one's).
RECENT_ITERATIONS = 10
__all__ = [
    "METRIC_COLUMNS",
    "Experiment",
    "validate_config",
    "CHECKPOINT_FILE",
    "CONFIG_FILE",
    "LEGACY_CHECKPOINT_FILE",
    "METRICS_FILE",
    "SNAPSHOT_FILE",
    "archive_from_checkpoint",
    "load_archive",
    "load_run_config",
    "select_elites",
]


def _leg_seconds(value: object) -> float | None:
    """``leg_seconds`` as a positive number of seconds, or None (run to the end)."""
    if value is None:
        return None
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not 0 < value < math.inf:
        raise NcaQdError(f"leg_seconds must be a positive number of seconds or null, got {value!r}")
    return float(value)


def _seconds(text: str | None) -> float | None:
    """A metrics.csv cell as finite seconds, or None (empty, nan, unreadable)."""
    try:
        value = float(text)  # type: ignore[arg-type]
    except (TypeError, ValueError):
        return None
    return value if math.isfinite(value) else None


def validate_config(cfg: DictConfig) -> None:
    """Check the numbers a user may override; raise one clear :class:`NcaQdError`."""

    def positive_int(path: str) -> None:
        value = OmegaConf.select(cfg, path)
        if isinstance(value, bool) or not isinstance(value, int) or value <= 0:
            raise NcaQdError(f"{path} must be a positive integer, got {value!r}")

    def positive_float(path: str) -> None:
        value = OmegaConf.select(cfg, path)
        if isinstance(value, bool) or not isinstance(value, (int, float)) or value <= 0:
            raise NcaQdError(f"{path} must be a positive number, got {value!r}")

    def optional(check: Callable[[str], None], path: str) -> None:
        if OmegaConf.select(cfg, path) is not None:
            check(path)

    for p in (
        "qd.n_evals",
        "qd.n_emitters",
        "qd.batch_size",
        "domain.nca_iters.train",
        "domain.nca_iters.eval",
    ):
        positive_int(p)
    positive_float("qd.sigma0")
    optional(positive_int, "qd.checkpoint_every")
    optional(positive_float, "qd.checkpoint_seconds")
    if not isinstance(cfg.seed, int) or isinstance(cfg.seed, bool):
        raise NcaQdError(f"seed must be an integer, got {cfg.seed!r}")
    for which in ("train", "eval"):
        size = OmegaConf.select(cfg, f"domain.size.{which}")
        if (
            size is None
            or len(size) != 2
            or not all(isinstance(s, int) and not isinstance(s, bool) and s > 1 for s in size)
        ):
            raise NcaQdError(f"domain.size.{which} must be two integers > 1, got {size!r}")
    if OmegaConf.select(cfg, "algo.name") == "map_elites":
        positive_float("algo.initial_sigma")
        for path in ("algo.iso_sigma", "algo.line_sigma"):
            value = OmegaConf.select(cfg, path)
            if isinstance(value, bool) or not isinstance(value, (int, float)) or value < 0:
                raise NcaQdError(f"{path} must be a number >= 0, got {value!r}")
        n_initial = OmegaConf.select(cfg, "algo.n_initial")
        if isinstance(n_initial, bool) or not isinstance(n_initial, int) or n_initial < 0:
            raise NcaQdError(f"algo.n_initial must be an integer >= 0, got {n_initial!r}")
    for path in ("qd.progress", "output.pictures", "output.repaired"):
        if OmegaConf.select(cfg, path) is not None:
            require_bool(path, OmegaConf.select(cfg, path))
    kept = OmegaConf.select(cfg, "output.kept_elites", default=0)
    if isinstance(kept, bool) or not isinstance(kept, int) or kept < 0:
        raise NcaQdError(f"output.kept_elites must be an integer >= 0, got {kept!r}")
    lr = OmegaConf.select(cfg, "qd.archive.learning_rate")
    if not isinstance(lr, (int, float)) or not 0 <= lr <= 1:
        raise NcaQdError(f"qd.archive.learning_rate must be in [0, 1], got {lr!r}")


class Experiment:
    """Builds domain, generator and QD loop from a config and runs it in a directory."""

    def __init__(self, cfg: DictConfig, run_dir: Path):
        validate_config(cfg)
        self.cfg, self.run_dir = cfg, Path(run_dir)
        self.domain: Domain = make_domain(cfg.domain)
        self.generator = make_generator(self.domain, cfg.algo.name)
        spec = archive_spec(cfg.algo, cfg.domain, cfg.qd)
        self.objective = make_objective(self.domain, self.generator, cfg)
        if cfg.algo.name == "dsage":  # direct search over layouts with a deep surrogate
            from nca_qd.qd.dsage import DSAGELoop

            algo = OmegaConf.to_container(cfg.algo, resolve=True)
            per_domain = OmegaConf.to_container(cfg.domain.get("dsage") or {}, resolve=True)
            if algo.get("downsample") is None:
                algo["downsample"] = per_domain.get("downsample")
            if algo["downsample"] is None:
                raise NcaQdError(f"algo=dsage needs algo.downsample (domain {cfg.domain.name} sets none)")
            obj_range = per_domain.get("objective_range") or list(cfg.domain.objective_range)
            if obj_range[1] is None:
                raise NcaQdError("algo=dsage needs domain.dsage.objective_range with an upper bound")
            self.loop = DSAGELoop(
                self.objective,
                self.domain.gen_shape("train"),
                self.domain.n_tiles,
                spec,
                (float(obj_range[0]), float(obj_range[1])),
                int(cfg.qd.n_evals),
                algo,
            )
        else:
            emitter = make_emitter(cfg.algo, cfg.qd, self.generator.n_params)
            self.loop = QDLoop(emitter, self.objective, self.generator.n_params, spec)
        # The algorithm's and the scorer's own per-iteration figures (surrogate error; exact
        # runs, screen error, stage timings).
        self.metric_columns = (
            METRIC_COLUMNS + list(getattr(self.loop, "metric_names", ())) + list(self.objective.metric_names)
        )
        # DSAGE's outer iterations evaluate varying numbers of layouts: its end is a budget of
        # evaluations; the other algorithms' a number of equal iterations.
        self.n_iterations = (
            None if hasattr(self.loop, "finished") else math.ceil(cfg.qd.n_evals / self.loop.batch_size)
        )
        self.checkpoint_policy = checkpoint.CheckpointPolicy.from_config(
            OmegaConf.to_container(cfg.checkpoint) if cfg.get("checkpoint") is not None else None
        )
        snap = cfg.get("snapshot") or {}
        enabled = snap.get("enabled", "auto")
        if enabled == "auto":  # a run kept under results/ is one meant for git: it needs its snapshot
            enabled = "results" in Path(run_dir).resolve().parts
        if not isinstance(enabled, bool):
            raise NcaQdError(f"snapshot.enabled must be true, false or auto, got {snap.get('enabled')!r}")
        base = self.checkpoint_policy
        snapshot_policy = checkpoint.CheckpointPolicy(  # validated even while disabled
            exact=False,
            restart_dtype="int8",
            covariance_rank=base.covariance_rank,
            covariance_tolerance=base.covariance_tolerance,
            exact_elites=snap.get("exact_elites", 64),
        )
        self.snapshot_policy = snapshot_policy if enabled else None
        # What the checkpoint's results depend on beyond the config (the exact simulator), and
        # the simulators that scored earlier iterations of a run resumed across a change.
        self.simulator = getattr(self.objective.evaluator, "simulator_version", None)
        self.simulator_history: list[dict] = []
        self.allow_simulator_change = require_bool(
            "allow_simulator_change", cfg.get("allow_simulator_change", False)
        )
        self.leg_seconds = _leg_seconds(cfg.get("leg_seconds"))
        self.leg_ended = False  # set by run() when leg_seconds ended it before the search's end

    # --- state on disk -------------------------------------------------------------------
    def initial_state(self) -> QDState:
        return self.loop.init(jax.random.PRNGKey(self.cfg.seed))

    def save_checkpoint(self, state: QDState, wall: float) -> None:
        # The scorer's memo first: on resume it is cut back to the checkpoint's iteration,
        # so a kill between the two writes loses nothing and replays the same search.
        t0 = time.perf_counter()
        self.objective.save_state(self.run_dir)
        if hasattr(self.loop, "save_state"):  # DSAGE's training data
            self.loop.save_state(self.run_dir)
        meta = {
            "wall_seconds": float(wall),
            "algo": str(self.cfg.algo.name),
            "domain": str(self.cfg.domain.name),
            "dim": int(self.loop.dim),
            "simulator": self.simulator,
            "simulator_history": self.simulator_history,
        }
        checkpoint.save_checkpoint(
            self.run_dir / CHECKPOINT_FILE, state, self.loop.emitter, self.checkpoint_policy, meta
        )
        if self.snapshot_policy is not None:
            checkpoint.save_checkpoint(
                self.run_dir / SNAPSHOT_FILE,
                state,
                self.loop.emitter,
                self.snapshot_policy,
                {**meta, "snapshot": True},
                compress=True,  # it ships: int8 restart points and float32 elites, ~11 % smaller
            )
        legacy = self.run_dir / LEGACY_CHECKPOINT_FILE
        if legacy.exists():  # superseded by the sparse checkpoint just written
            legacy.unlink()
            log.info("replaced the dense %s by %s", LEGACY_CHECKPOINT_FILE, CHECKPOINT_FILE)
        log.debug("checkpoint written in %.2f s", time.perf_counter() - t0)

    def load_checkpoint(self) -> tuple[QDState, float]:
        path = self.run_dir / CHECKPOINT_FILE
        legacy = self.run_dir / LEGACY_CHECKPOINT_FILE
        if not path.is_file() and (self.run_dir / SNAPSHOT_FILE).is_file():
            path = self.run_dir / SNAPSHOT_FILE
            log.info("no %s: resuming from the portable %s", CHECKPOINT_FILE, SNAPSHOT_FILE)
        if path.is_file():
            state, meta = checkpoint.load_checkpoint(path, self.initial_state(), self.loop.emitter)
            saved = meta.get("simulator")
            self.simulator_history = list(meta.get("simulator_history", []))
            if saved is not None and self.simulator is not None and saved != self.simulator:
                if not self.allow_simulator_change:
                    raise NcaQdError(
                        f"{path} was scored with exact simulator {saved}, this nca-qd has "
                        f"{self.simulator}: its archive would mix two simulators; start a new run, "
                        "use the nca-qd version that made it, or continue anyway with "
                        "allow_simulator_change=true (recorded in the checkpoint)"
                    )
                # The archive keeps the scores of the old simulator; new evaluations use the new
                # one (the memo's fingerprint drops the old exact runs). Recorded for readers.
                self.simulator_history.append({"simulator": saved, "until_iteration": int(state.iteration)})
                log.warning(
                    "%s was scored with exact simulator %s up to iteration %d; continuing with %s "
                    "(allow_simulator_change=true)",
                    path,
                    saved,
                    int(state.iteration),
                    self.simulator,
                )
            wall = float(meta.get("wall_seconds", 0.0))
        elif legacy.is_file():
            log.info("resuming from a dense %s of an earlier version", LEGACY_CHECKPOINT_FILE)
            tree = load_pytree(legacy, {"state": self.initial_state(), "wall_seconds": np.float64(0)})
            state, wall = tree["state"], float(tree["wall_seconds"])
        else:
            missing = f"neither {CHECKPOINT_FILE} nor {SNAPSHOT_FILE}"
            raise NcaQdError(f"{self.run_dir}: no checkpoint to resume from ({missing})")
        self.objective.restore_state(self.run_dir, int(state.iteration))
        if hasattr(self.loop, "restore_state"):
            self.loop.restore_state(self.run_dir, state)
        return state, wall

    def _metrics_rows(self, upto: int) -> list[dict[str, str]]:
        path = self.run_dir / METRICS_FILE
        if not path.is_file():
            return []
        with path.open() as fh:
            return [r for r in csv.DictReader(fh) if int(r["iteration"]) <= upto]

    # --- the run -------------------------------------------------------------------------
    def run(self, resume: bool = False) -> QDState:
        """Run (or continue) until ``qd.n_evals`` evaluations; returns the final state."""
        preload()  # the run reads its source now: later edits to the tree cannot reach it
        self.run_dir.mkdir(parents=True, exist_ok=True)
        # allow_simulator_change and leg_seconds are one invocation's decisions: the saved config
        # never carries them, so a later resume under yet another simulator is refused again and
        # a resume without leg_seconds runs to the end.
        saved = OmegaConf.masked_copy(self.cfg, [k for k in self.cfg if k not in INVOCATION_KEYS])
        if resume:  # first: a run directory that cannot be resumed is left as it was
            state, wall = self.load_checkpoint()
            log.info("resuming %s at iteration %d", self.run_dir, int(state.iteration))
        else:
            state, wall = self.initial_state(), 0.0
        atomic_write_text(self.run_dir / CONFIG_FILE, OmegaConf.to_yaml(saved))
        rows = self._metrics_rows(int(state.iteration))
        metrics_path = self.run_dir / METRICS_FILE
        with metrics_path.open("w", newline="") as fh:  # rewrite: drops rows past the checkpoint
            writer = csv.DictWriter(fh, fieldnames=self.metric_columns, extrasaction="ignore")
            writer.writeheader()
            writer.writerows(rows)
        recent = [_seconds(r.get("step_seconds")) for r in rows[-RECENT_ITERATIONS:]]
        try:
            state = self._iterate(state, wall, [x for x in recent if x is not None])
            if self.leg_ended:
                log.info(
                    "leg of %s s ended at iteration %d (%d evaluations), before the search's end; "
                    "continue with resume=%s",
                    f"{self.leg_seconds:g}",
                    int(state.iteration),
                    int(state.evaluations),
                    self.run_dir,
                )
            else:
                self.write_outputs(state)
        finally:
            self.objective.close()
        return state

    def _iterate(self, state: QDState, wall: float, recent: list[float]) -> QDState:
        """Step until the search's end (or, with ``leg_seconds``, until the next iteration
        would not end in time: the estimate of the next one is the longest of this leg's last
        iterations or, before it has run one, of ``recent``, the run's last recorded ones);
        checkpoint as configured and on the way out."""
        from tqdm import tqdm

        cfg = self.cfg
        leg_start = time.monotonic()
        start_iter = int(state.iteration)
        by_evals = self.n_iterations is None
        bar = tqdm(
            total=int(cfg.qd.n_evals) if by_evals else self.n_iterations,
            initial=int(state.evaluations) if by_evals else start_iter,
            disable=not cfg.qd.progress,
            desc=f"{cfg.algo.name} {cfg.domain.name}",
            unit="eval" if by_evals else "it",
            dynamic_ncols=True,
        )
        every = cfg.algo.get("checkpoint_every", cfg.qd.get("checkpoint_every"))
        every_seconds = cfg.qd.get("checkpoint_seconds")  # absent from configs saved before it
        last_saved = start_iter
        saved_at = time.perf_counter()
        # wall_seconds counts everything since the last row (the step, the row, the checkpoint
        # and log that followed it): with fast steps (the maze on a GPU) checkpoints can take
        # most of a search's time, and a search's cost must show them.
        mark = time.perf_counter()
        own: list[float] = []  # this leg's iterations (another machine may have recorded recent)
        try:
            while not self._finished(state):
                if self._leg_over(leg_start, own or recent):
                    if int(state.iteration) != last_saved:
                        self.save_checkpoint(state, wall)
                        last_saved = int(state.iteration)
                    self.leg_ended = True
                    break
                new_state, metrics, _ = self.loop.step(state)
                now = time.perf_counter()
                metrics["wall_seconds"] = wall + now - mark
                mark = now
                # Opened per row, not held for the leg: a metrics.csv replaced meanwhile (e.g.
                # by a git checkout of a shipped run) gets the row instead of a deleted file.
                with (self.run_dir / METRICS_FILE).open("a", newline="") as fh:
                    writer = csv.DictWriter(fh, fieldnames=self.metric_columns, extrasaction="ignore")
                    writer.writerow(metrics)
                # Only now does the new state count: a Ctrl-C before this line leaves a
                # metrics row past the checkpoint, which resume drops and recomputes.
                done = int(new_state.evaluations) - int(state.evaluations) if by_evals else 1
                own = (own + [float(metrics["step_seconds"])])[-RECENT_ITERATIONS:]
                state, wall = new_state, metrics["wall_seconds"]
                bar.update(done)
                bar.set_postfix(qd=f"{metrics['qd_score']:.4g}", cov=f"{metrics['coverage']:.3f}")
                it = metrics["iteration"]
                due_by_count = every is not None and it % int(every) == 0
                due_by_time = every_seconds is not None and now - saved_at >= float(every_seconds)
                if due_by_count or due_by_time or self._finished(state):
                    self.save_checkpoint(state, wall)
                    last_saved = it
                    saved_at = time.perf_counter()
                    log.info(
                        "iter %d/%s evals %d qd_score %.4g coverage %.4f best %.4g (%.3f s/iter)",
                        it,
                        "?" if by_evals else self.n_iterations,
                        metrics["evaluations"],
                        metrics["qd_score"],
                        metrics["coverage"],
                        metrics["best_objective"],
                        metrics["step_seconds"],
                    )
        except KeyboardInterrupt:
            if int(state.iteration) != last_saved:
                self.save_checkpoint(state, wall)
            bar.close()
            raise
        bar.close()
        return state

    def _leg_over(self, leg_start: float, recent: list[float]) -> bool:
        """Would the next iteration end past ``leg_seconds`` (counted from the loop's start)?
        Without any iteration to judge by, one is run."""
        if self.leg_seconds is None or not recent:
            return False
        return time.monotonic() - leg_start + max(recent) > self.leg_seconds

    def _finished(self, state: QDState) -> bool:
        if self.n_iterations is None:
            return self.loop.finished(state)
        return int(state.iteration) >= self.n_iterations

    # --- outputs -------------------------------------------------------------------------
    def write_outputs(self, state: QDState) -> None:
        """Both archives as ``.npz``, the elites record and, unless ``output.pictures=false``,
        every picture (:mod:`nca_qd.run_pictures`)."""
        spec = self.loop.spec
        views = {}
        # A configuration saved before the record existed has no kept_elites: none written.
        n_kept = int(OmegaConf.select(self.cfg, "output.kept_elites", default=0))
        for which, archive in (("result", state.res_archive), ("opt", state.opt_archive)):
            elites = checkpoint.archive_elites(archive)
            archive_io.save_archive(self.run_dir / f"archive_{which}.npz", elites, spec.cells, spec.ranges)
            views[which] = archive_io.archive_view(elites, spec.cells, spec.ranges)
            if which == "result" and n_kept:
                objective = views[which]["objective"]  # kept too: the elites the pictures draw
                kept = np.union1d(
                    select_elites(objective, n_kept), select_elites(objective, self.cfg.output.n_best)
                )
                archive_io.save_elites_record(
                    self.run_dir / ELITES_FILE, elites, kept, spec.cells, spec.ranges
                )
        if self.cfg.output.pictures:
            from nca_qd.run_pictures import write_run_pictures

            write_run_pictures(self.run_dir, self.cfg, views, self.domain, self.generator)
