"""Score one QD batch of warehouse / manufacturing layouts: repair -> screen -> exact RHCR.

Per batch (paper §4 with the design's screening step):

1. **Repair** every generated layout (HiGHS, in parallel on the evaluation backend). A layout
   whose repair finds nothing, or fails, is recorded as invalid: lowest objective, not inserted.
2. **Measures** of the repaired layouts (the domain's, e.g. entropy and shelf components).
3. **Screen** the repaired layouts with the JAX simulator, all of them x N_e seeds as one
   vmapped batch (:mod:`nca_qd.sim.screen`) — except those whose result-archive cell is
   still empty: they get exact runs whatever the screen says, so screening them would only
   measure the screen; a random ``exact_random_share`` of them is screened for that
   (``screen_empty_cells: true`` screens them all). Early in a search most cells are empty
   and this saves most of the screen's time.
   The crowding rule's threshold is the domain's (``simulation.screen_crowd_mean``: traffic
   that crowds more where it flows, like the uneven warehouse's, needs a higher one).
   The screen's runs predict RHCR's throughput (``screen_estimate``): ``free_flow`` gives a
   layout whose screened runs all flowed RHCR's share of its free-flow throughput
   (:func:`nca_qd.sim.free_flow.rhcr_estimate`; the share, ``screen_efficiency``, is
   recalibrated on the search's own flowing exact runs once it has
   :data:`MIN_CALIBRATION_RUNS`), one with a congested run a share fitted on the screen's
   throughput and stop times (``screen_congested``); ``scaled`` counts every run
   ``screen_scale`` x its own. On the
   search's own layouts and on held-out ones the first ranks RHCR's throughput better
   (``benchmarks/bench_screen.py``).
4. **Exact RHCR** (parallel, on the backend) for the layouts whose predicted throughput
   could place them in the result archive:
   their cell is empty, or ``scaled * (1 + exact_margin) >= `` the cell's elite; plus a random
   ``exact_random_share`` of the rest, as a running check on the screen. ``exact: all``
   simulates every layout exactly (and ``screen: false`` skips the screen, implying ``all``).

**Memo** (``eval.memo``, on by default; :mod:`nca_qd.scoring.memo`): nearby CMA-ES samples
often generate the same layout, so each distinct generated layout is repaired once and each
distinct repaired layout simulated exactly once per search; copies take the remembered result
(and skip the screen). ``repair_reused`` / ``exact_reused`` count them per iteration; the memo
is saved beside each checkpoint (``eval_memo.npz``) so a resumed run keeps it.

Objectives: f_res = mean exact throughput over the N_e runs (the result archive takes only
layouts with exact runs); f_opt = f + alpha * Delta with f = f_res, or the screen's prediction
where no exact run was made. Per iteration the metrics record how many exact runs were made,
the screen's error on them (prediction minus exact, mean and mean absolute), the free-flow
estimate's efficiency in use, and the time spent in each stage (``generate_seconds`` comes
from :mod:`nca_qd.pipeline`).
"""

from __future__ import annotations

import json
import logging
import time
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from nca_qd.errors import NcaQdError
from nca_qd.interfaces import EvalBatch, ScoringContext, wants_ancillary
from nca_qd.io import array_to_rows
from nca_qd.scoring import phases
from nca_qd.scoring.backend import JobFailed, make_backend, map_jobs
from nca_qd.scoring.jobs import (
    ExactSettings,
    RepairOutcome,
    RunOutcome,
    exact_job,
    repair_job,
    repair_options,
)
from nca_qd.scoring.keys import layout_key, memo_repair_options
from nca_qd.scoring.memo import MEMO_FILE, EvalMemo, first_of_each
from nca_qd.scoring.settings import ScoringConfig
from nca_qd.sim.free_flow import free_flow_throughput, rhcr_estimate
from nca_qd.sim.rhcr import REPLAN as RHCR_REPLAN
from nca_qd.sim.rhcr import VERSION as RHCR_VERSION
from nca_qd.sim.rhcr import WINDOW as RHCR_WINDOW
from nca_qd.sim.screen import crowd_mean_for

log = logging.getLogger(__name__)

# Exact runs that flowed before the search's own calibrate the free-flow estimate's efficiency
# (until then the configured prior holds).
MIN_CALIBRATION_RUNS = 50
METRIC_NAMES = (
    "n_valid",
    "n_exact",
    "exact_runs",
    "screen_bias",
    "screen_mae",
    "screen_efficiency",
    "repair_reused",
    "exact_reused",
    "generate_seconds",
    "repair_seconds",
    "screen_seconds",
    "exact_seconds",
)


def choose_exact(
    predicted: np.ndarray, elite: np.ndarray, valid: np.ndarray, cfg: ScoringConfig, rng: np.random.Generator
) -> np.ndarray:
    """Which layouts get exact runs: those that could enter the result archive, plus a random
    share of the others (``valid`` only)."""
    if cfg.exact == "all":
        return valid.copy()
    could = ~np.isfinite(elite) | (predicted * (1.0 + cfg.exact_margin) >= elite)
    check = rng.random(predicted.shape) < cfg.exact_random_share
    return valid & (could | check)


def screen_bucket(n: int, cap: int | None = None) -> int:
    """The batch size a screen of ``n`` layouts is padded to: the next power of two, at most
    ``cap`` (the QD batch size: a full batch is not padded)."""
    size = 1 << max(0, int(n) - 1).bit_length()
    return max(int(n), min(size, cap)) if cap is not None else size


@dataclass
class _Work:
    """What the stages of one batch hand on to each other (arrays are per layout)."""

    layouts: np.ndarray  # as generated
    seeds: list[int]
    rng: np.random.Generator
    iteration: int
    seconds: dict[str, float] = field(default_factory=dict)
    repaired: list[RepairOutcome] = field(default_factory=list)
    repair_reused: int = 0
    ok: np.ndarray = field(default_factory=lambda: np.zeros(0, bool))  # still valid
    fixed: np.ndarray = field(default_factory=lambda: np.zeros(0))  # repaired (else generated)
    similarity: np.ndarray = field(default_factory=lambda: np.zeros(0))  # Delta of the repair
    rows: list[list[str] | None] = field(default_factory=list)
    keys: list[bytes] = field(default_factory=list)
    measures: np.ndarray = field(default_factory=lambda: np.zeros(0))
    elite: np.ndarray = field(default_factory=lambda: np.zeros(0))  # result cell's objective
    known: np.ndarray = field(default_factory=lambda: np.zeros(0))  # remembered exact mean
    fresh: np.ndarray = field(default_factory=lambda: np.zeros(0, bool))
    screened: np.ndarray = field(default_factory=lambda: np.zeros(0))  # mean screened throughput
    predicted: np.ndarray = field(default_factory=lambda: np.zeros(0))  # RHCR's, from the screen
    free_flow: np.ndarray = field(default_factory=lambda: np.zeros(0))  # NaN: not computed
    run_exact: np.ndarray = field(default_factory=lambda: np.zeros(0, bool))
    exact: np.ndarray = field(default_factory=lambda: np.zeros(0))
    visits: np.ndarray | None = None  # [b, H, W] tile usage of the exact runs (ancillary only)
    n_simulated: int = 0  # distinct layouts given exact runs now


class MapfScorer:
    """The evaluator of a multi-agent domain: ``scorer(regions, key, context) -> EvalBatch``."""

    metric_names = METRIC_NAMES

    def __init__(self, domain: Any, run_cfg: Mapping[str, Any] | None = None):
        run_cfg = run_cfg or {}
        dcfg = domain.cfg
        self.domain = domain
        self.cfg = ScoringConfig.from_cfg(run_cfg.get("eval"))
        sim = dcfg["simulation"]
        self.T, self.n_runs = int(sim["T"]), int(sim["n_runs"])
        self.crowd_mean = crowd_mean_for(dcfg)  # the screen's crowding threshold for this traffic
        if self.T <= 0 or self.n_runs <= 0:
            raise NcaQdError(
                f"domain.simulation needs T > 0 and n_runs > 0, got T={self.T}, n_runs={self.n_runs}"
            )
        self.n_agents = int(dcfg["n_agents"]["train"])
        alpha = run_cfg.get("alpha")
        self.alpha = float(dcfg["alpha"] if alpha is None else alpha)
        self.failed_objective = float(dcfg.get("failed_repair_objective", 0.0))
        self.repair_opts = repair_options(dcfg, "train")
        self.exact_settings = ExactSettings(
            self.T, self.cfg.exact_time_limit_s, RHCR_WINDOW, RHCR_REPLAN, dict(self.cfg.planner or {})
        )
        self.backend = make_backend(run_cfg.get("eval"))
        # The simulator a checkpoint's archive was scored with (a resume under another is refused).
        self.simulator_version = f"rhcr {RHCR_VERSION}"
        # What remembered results depend on: a memo made under other settings is not used.
        settings = {
            "domain": domain.name,
            "n_agents": self.n_agents,
            "T": self.T,
            "n_runs": self.n_runs,
            "repair": memo_repair_options(self.repair_opts),
            "exact_time_limit_s": self.cfg.exact_time_limit_s,
            "rhcr_version": RHCR_VERSION,
        }
        if self.cfg.planner:  # (absent when unset: memos of runs with the defaults stay valid)
            settings["planner"] = self.cfg.planner
        # DSAGE's ancillary target: the exact runs' tile usage (mean robots per step on each
        # tile), remembered with their throughput.
        self.ancillary = wants_ancillary(run_cfg)
        if self.ancillary:
            settings["tile_usage"] = True
        self.fingerprint = json.dumps(settings, sort_keys=True, default=str)
        self.memo: EvalMemo | None = EvalMemo(self.fingerprint) if self.cfg.memo else None
        # exact throughput / free flow of the search's flowing exact runs (free-flow estimate)
        self._flow_shares: list[np.ndarray] = []
        log.info(
            "%s scoring: %s; screen %s (%s estimate, crowding threshold %g), exact %s",
            domain.name,
            self.backend.describe(),
            "on" if self.cfg.screen else "off",
            self.cfg.screen_estimate,
            self.crowd_mean,
            self.cfg.exact,
        )

    # ------------------------------------------------------------------------------ stages
    def repair(self, layouts: np.ndarray) -> list[RepairOutcome]:
        jobs = [(self.domain.name, lay, self.repair_opts) for lay in layouts]
        out = map_jobs(self.backend, repair_job, jobs)
        return [
            o if isinstance(o, RepairOutcome) else RepairOutcome(None, "error", 0.0, None, 0.0, o.error)
            for o in out
        ]

    def screen(self, rows: list[list[str]], seeds: list[int], cap: int | None = None) -> np.ndarray:
        """Mean screened throughput per layout ``[n]`` (NaN where the screen failed)."""
        return self.screen_runs(rows, seeds, cap)[0].mean(axis=1)

    def screen_runs(
        self, rows: list[list[str]], seeds: list[int], cap: int | None = None
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Screened throughput, success and stop time / T per layout and seed
        ``[n, len(seeds)]`` (NaN, False, NaN where the screen failed), and with the free-flow
        estimate each layout's free-flow throughput ``[n]`` (else NaN)."""
        from nca_qd.sim.scenario import build_scenario
        from nca_qd.sim.screen import simulate_scenarios

        thr = np.full((len(rows), len(seeds)), np.nan)
        ok = np.zeros((len(rows), len(seeds)), bool)
        stop = np.full((len(rows), len(seeds)), np.nan)
        flow = np.full(len(rows), np.nan)
        scens, keep = [], []
        for i, r in enumerate(rows):
            try:
                scens.append(build_scenario(r, self.domain.name, n_agents=self.n_agents))
                keep.append(i)
            except NcaQdError as exc:
                log.warning("screen: layout %d rejected: %s", i, exc)
        if scens:
            # The number of screened layouts varies per batch (see _to_screen); padding it to
            # a power of two (repeating the last layout) bounds the compiled batch shapes to
            # a handful instead of one compilation per new count.
            n = len(scens)
            padded = scens + [scens[-1]] * (screen_bucket(n, cap) - n)
            res = simulate_scenarios(padded, self.n_agents, self.T, seeds, crowd_mean=self.crowd_mean)[:n]
            thr[keep] = [[r.throughput for r in row] for row in res]
            ok[keep] = [[r.success for r in row] for row in res]
            stop[keep] = [[r.stop_time / self.T for r in row] for row in res]
            if self.cfg.screen_estimate == "free_flow":
                flow[keep] = [free_flow_throughput(s, self.n_agents) for s in scens]
        return thr, ok, stop, flow

    def free_flow(self, rows: list[list[str]]) -> np.ndarray:
        """Free-flow throughput per layout ``[n]`` (NaN where the scenario is rejected)."""
        from nca_qd.sim.scenario import build_scenario

        out = np.full(len(rows), np.nan)
        for i, r in enumerate(rows):
            try:
                out[i] = free_flow_throughput(
                    build_scenario(r, self.domain.name, n_agents=self.n_agents), self.n_agents
                )
            except NcaQdError:
                pass
        return out

    @property
    def efficiency(self) -> float:
        """RHCR's share of free flow where it flows: the mean over the search's own flowing
        exact runs once there are :data:`MIN_CALIBRATION_RUNS`, else the configured prior."""
        shares = np.concatenate(self._flow_shares) if self._flow_shares else np.zeros(0)
        return float(shares.mean()) if shares.size >= MIN_CALIBRATION_RUNS else self.cfg.screen_efficiency

    def exact(self, rows: list[list[str]], seeds: list[int]) -> np.ndarray:
        """Exact RHCR throughput per layout and seed ``[n, len(seeds)]`` (NaN where a run failed)."""
        return self._exact_runs(rows, seeds)[0]

    def _exact_runs(
        self, rows: list[list[str]], seeds: list[int]
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
        """:meth:`exact`, each run's verdict ``[n, len(seeds)]``, and with the ancillary target
        each layout's tile usage ``[n, H, W]`` (visits / T, averaged over its runs; NaN where a
        run failed)."""
        jobs = [
            (r, self.domain.name, self.n_agents, s, self.exact_settings, self.ancillary)
            for r in rows
            for s in seeds
        ]
        out = map_jobs(self.backend, exact_job, jobs)
        good = [isinstance(o, RunOutcome) and o.error is None for o in out]
        tp = np.array([o.throughput if ok else np.nan for o, ok in zip(out, good)]).reshape(
            len(rows), len(seeds)
        )
        success = np.array([bool(ok and o.success) for o, ok in zip(out, good)]).reshape(tp.shape)
        for o in out:
            err = o.error if isinstance(o, (RunOutcome, JobFailed)) else None
            if err:
                log.warning("exact run failed: %s", err)
        visits = None
        if self.ancillary and rows:
            shape = (len(rows[0]), len(rows[0][0]))
            per_run = np.stack(
                [
                    np.asarray(o.tile_visits, np.float64) / self.T if ok else np.full(shape, np.nan)
                    for o, ok in zip(out, good)
                ]
            )
            visits = per_run.reshape(len(rows), len(seeds), *shape).mean(axis=1)
        return tp, success, visits

    def _distinct(self, keys: list[bytes]) -> tuple[np.ndarray, np.ndarray]:
        """``(first, inverse)`` of :func:`first_of_each`; without a memo every layout is its
        own (copies are scored again, as the paper's search does)."""
        if self.memo is None:
            ar = np.arange(len(keys))
            return ar, ar
        return first_of_each(keys)

    def _repair_batch(self, layouts: np.ndarray, iteration: int) -> tuple[list[RepairOutcome], int]:
        """Each layout's repair: remembered, or made once per distinct layout. Returns the
        outcomes and how many came without a repair job of their own."""
        keys = [layout_key(lay) for lay in layouts]
        out: list[RepairOutcome | None] = [
            self.memo.repair(k) if self.memo is not None else None for k in keys
        ]
        todo = [i for i, o in enumerate(out) if o is None]
        first, inverse = self._distinct([keys[i] for i in todo])
        fresh = self.repair(layouts[[todo[j] for j in first]]) if todo else []
        for j, rep in zip(first, fresh):
            if self.memo is not None:
                self.memo.put_repair(keys[todo[j]], rep, iteration)
        for t, i in enumerate(todo):
            out[i] = fresh[inverse[t]]
        return out, len(layouts) - len(first)  # type: ignore[return-value]

    def _exact_batch(
        self,
        rows: list[list[str]],
        keys: list[bytes],
        seeds: list[int],
        iteration: int,
        free_flow: np.ndarray | None = None,
    ) -> tuple[np.ndarray, int, np.ndarray | None]:
        """Mean exact throughput per layout ``[n]``: one set of runs per distinct layout,
        remembered for the rest of the search. Also returns how many layouts were simulated and,
        with the ancillary target, their tile usage ``[n, H, W]``. With the free-flow estimate
        the flowing runs calibrate its efficiency (``free_flow``: the layouts' where known)."""
        first, inverse = self._distinct(keys)
        todo = [rows[j] for j in first]
        tp, success, visits = self._exact_runs(todo, seeds)
        flow = np.full(len(first), np.nan)
        if self.cfg.screen_estimate == "free_flow":
            flow = np.asarray(free_flow, float)[first] if free_flow is not None else flow
            missing = np.flatnonzero(np.isnan(flow))
            flow[missing] = self.free_flow([todo[i] for i in missing])
            done = np.isfinite(tp).all(axis=1) & (flow > 0)
            if done.any():
                self._flow_shares.append((tp[done] / flow[done, None])[success[done]])
        for i, (j, runs) in enumerate(zip(first, tp)):
            if self.memo is not None:
                self.memo.put_exact(
                    keys[j], runs, iteration, None if visits is None else visits[i], success[i], flow[i]
                )
        return tp.mean(axis=1)[inverse], len(first), None if visits is None else visits[inverse]

    def _to_screen(self, valid: np.ndarray, elite: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        """Which valid layouts the screen runs on: all of them, or (by default) those whose
        result cell holds an elite plus a random share of the rest (exact runs follow for
        every empty cell anyway; the share keeps measuring the screen's error there)."""
        if not self.cfg.screen:
            return np.zeros_like(valid)
        if self.cfg.exact == "all" or self.cfg.screen_empty_cells:
            return valid.copy()
        sample = rng.random(valid.shape) < self.cfg.exact_random_share
        return valid & (np.isfinite(elite) | sample)

    # ------------------------------------------------------------------------------ memo
    def save_state(self, run_dir: str | Path) -> None:
        """Write the evaluation memo into a run directory (before its checkpoint)."""
        if self.memo is not None:
            self.memo.save(Path(run_dir) / MEMO_FILE)

    def restore_state(self, run_dir: str | Path, iteration: int) -> None:
        """Resume: the run directory's memo, as it was after ``iteration``."""
        if self.memo is not None:
            self.memo = EvalMemo.load(Path(run_dir) / MEMO_FILE, self.memo.fingerprint, iteration)
            self._flow_shares = [self.memo.flowing_shares()]
            log.info("evaluation memo: %d entries up to iteration %d", len(self.memo), iteration)

    # ------------------------------------------------------------------------------ batch
    def __call__(self, regions, key, context: ScoringContext | None = None) -> EvalBatch:
        """Score one batch, one stage after the other (see the module docstring). ``regions``
        ``[b, H, W]``, or ``[b, P, H, W]``: each generator's ``eval.phases`` NCA phases
        (:mod:`nca_qd.scoring.phases`)."""
        regions = np.asarray(regions)
        phases = regions.shape[1] if regions.ndim == 4 else 1
        if phases != self.cfg.phases:
            raise ValueError(f"eval.phases is {self.cfg.phases}, the batch holds {phases} phase(s)")
        flat = regions.reshape(-1, *regions.shape[-2:])
        layouts = np.stack([self.domain.assemble(r) for r in flat])
        seeds, rng = self._seeds(key)
        iteration = context.iteration if context is not None else 0
        work = _Work(layouts=layouts, seeds=seeds, rng=rng, iteration=iteration)
        self._stage_repair(work)
        self._stage_measures(work, context)
        self._stage_screen(work)
        self._stage_choose(work)
        self._stage_exact(work)
        return self._stage_assemble(work)

    def _seeds(self, key) -> tuple[list[int], np.random.Generator]:
        """The batch's N_e simulation seeds and its random stream (screen and exact choice)."""
        seed0 = int(np.asarray(key, dtype=np.uint32).ravel()[-1] % np.uint32(2**31 - 1))
        return [seed0 + i for i in range(self.n_runs)], np.random.default_rng(seed0)

    def _stage_repair(self, w: _Work) -> None:
        """Repair every layout (memo first); a failed repair leaves the layout invalid."""
        t = time.perf_counter()
        w.repaired, w.repair_reused = self._repair_batch(w.layouts, w.iteration)
        w.seconds["repair_seconds"] = time.perf_counter() - t
        w.ok = np.array([r.layout is not None for r in w.repaired])
        for i, r in enumerate(w.repaired):
            if r.layout is None:
                log.warning("repair of layout %d: %s%s", i, r.status, f" ({r.error})" if r.error else "")
        w.fixed = np.stack(
            [r.layout if r.layout is not None else w.layouts[i] for i, r in enumerate(w.repaired)]
        )
        w.similarity = np.array([r.similarity for r in w.repaired])
        tiles = self.domain.layout_tiles
        w.rows = [array_to_rows(lay, tiles) if good else None for lay, good in zip(w.fixed, w.ok)]
        w.keys = [layout_key(lay) for lay in w.fixed]

    def _stage_measures(self, w: _Work, context: ScoringContext | None) -> None:
        """The repaired layouts' measures, their result cells' elites, and the exact results
        the memo already holds (those layouts need neither screen nor exact runs)."""
        b = len(w.layouts)
        w.measures = np.asarray(self.domain.measures(w.fixed), dtype=np.float32)
        p = self.cfg.phases  # each phase is compared with the elite of its generator's cell
        phase_c = phases.first_phase(w.measures, p)  # the generators' measures
        elite = np.asarray(context.result_elite(phase_c)) if context is not None else np.full(b // p, -np.inf)
        w.elite = phases.spread(elite, p)
        w.known = np.full(b, np.nan)
        if self.ancillary:
            w.visits = np.full(w.fixed.shape, np.nan)
        if self.memo is not None:
            for i in np.flatnonzero(w.ok):
                runs = self.memo.exact(w.keys[i])
                w.known[i] = np.nan if runs is None else runs.mean()
                seen = self.memo.visits(w.keys[i]) if self.ancillary and runs is not None else None
                if seen is not None and w.visits is not None:
                    w.visits[i] = seen
        w.fresh = w.ok & np.isnan(w.known)

    def _stage_screen(self, w: _Work) -> None:
        """Screen the chosen fresh layouts (each distinct one once); a failed screen
        invalidates its layout."""
        to_screen = self._to_screen(w.fresh, w.elite, w.rng)
        t = time.perf_counter()
        w.screened = np.full(len(w.layouts), np.nan)
        w.predicted = np.full(len(w.layouts), np.nan)
        w.free_flow = np.full(len(w.layouts), np.nan)
        sel = np.flatnonzero(to_screen)
        if sel.size:
            first, inverse = self._distinct([w.keys[i] for i in sel])
            thr, ok, stop, flow = self.screen_runs(
                [w.rows[sel[j]] for j in first], w.seeds, cap=len(w.layouts)
            )
            w.screened[sel] = thr.mean(axis=1)[inverse]
            w.free_flow[sel] = flow[inverse]
            if self.cfg.screen_estimate == "free_flow":
                # a rejected scenario has NaN runs and free flow: its estimate stays NaN
                estimate = rhcr_estimate(thr, ok, stop, flow, self.efficiency, self.cfg.screen_congested)
                w.predicted[sel] = np.where(np.isnan(thr).any(axis=1), np.nan, estimate)[inverse]
            else:
                w.predicted[sel] = w.screened[sel] * self.cfg.screen_scale
        w.seconds["screen_seconds"] = time.perf_counter() - t
        w.ok &= ~(to_screen & np.isnan(w.predicted))

    def _stage_choose(self, w: _Work) -> None:
        """Which fresh layouts get exact runs (:func:`choose_exact`)."""
        predicted = np.nan_to_num(w.predicted, nan=-np.inf)
        p = self.cfg.phases
        if p == 1:
            w.run_exact = choose_exact(predicted, w.elite, w.ok & w.fresh, self.cfg, w.rng)
            return
        # per generator: the lowest over its phases of what is known or predicted
        value = np.where(np.isfinite(w.known), w.known, predicted)
        chosen = choose_exact(
            phases.lowest(value, p),
            phases.first_phase(w.elite, p),
            phases.every(w.ok, p) & ~phases.every(~w.fresh, p),
            self.cfg,
            w.rng,
        )
        w.run_exact = phases.spread(chosen, p) & w.ok & w.fresh

    def _stage_exact(self, w: _Work) -> None:
        """Exact RHCR for the chosen layouts (each distinct one once, remembered)."""
        t = time.perf_counter()
        w.exact = w.known.copy()
        chosen = np.flatnonzero(w.run_exact)
        if chosen.size:
            w.exact[chosen], w.n_simulated, visits = self._exact_batch(
                [w.rows[i] for i in chosen],
                [w.keys[i] for i in chosen],
                w.seeds,
                w.iteration,
                w.free_flow[chosen],
            )
            if w.visits is not None and visits is not None:
                w.visits[chosen] = visits
        w.seconds["exact_seconds"] = time.perf_counter() - t

    def _stage_assemble(self, w: _Work) -> EvalBatch:
        """Objectives (f_opt = f + alpha * Delta; f_res from exact runs only), the
        iteration's metrics and the per-layout extras."""
        has_exact = ~np.isnan(w.exact)
        f = np.where(has_exact, w.exact, w.predicted)
        ok = w.ok & ~np.isnan(f)
        f_opt = np.where(ok, f + self.alpha * w.similarity, self.failed_objective)
        f_res = np.where(ok & has_exact, w.exact, self.failed_objective)
        both = has_exact & ~np.isnan(w.predicted)
        err = w.predicted[both] - w.exact[both]
        n_chosen = int(w.run_exact.sum())
        metrics = {
            "n_valid": int(ok.sum()),
            "n_exact": int(has_exact.sum()),
            "exact_runs": w.n_simulated * self.n_runs,
            "screen_bias": float(err.mean()) if err.size else float("nan"),
            "screen_mae": float(np.abs(err).mean()) if err.size else float("nan"),
            "screen_efficiency": self.efficiency if self.cfg.screen_estimate == "free_flow" else float("nan"),
            "repair_reused": int(w.repair_reused),
            "exact_reused": int(np.isfinite(w.known).sum() + n_chosen - w.n_simulated),
            **w.seconds,
        }
        extras = {
            "metrics": metrics,
            "repaired": w.fixed,
            "unrepaired": w.layouts,
            "similarity": w.similarity,
            "screened": w.screened,
            "exact": w.exact,
            "repair_status": [r.status for r in w.repaired],
            # tile usage over the generated region (NaN: no exact run of that layout)
            **({"ancillary": self.domain.layout.region(w.visits)} if w.visits is not None else {}),
        }
        valid, result_valid, measures = ok, ok & has_exact, w.measures
        if self.cfg.phases > 1:  # one generator, its lowest phase (nca_qd/scoring/phases.py)
            f_opt, f_res, valid, result_valid, measures, extras = phases.combine(
                f_opt, f_res, ok, has_exact, w.measures, extras, self.cfg.phases, self.failed_objective
            )
        return EvalBatch(
            objective=f_opt.astype(np.float32),
            measures=measures,
            result_objective=f_res.astype(np.float32),
            valid=valid,
            result_valid=result_valid,
            extras=extras,
        )

    def close(self) -> None:
        self.backend.close()
