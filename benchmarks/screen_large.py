"""The screen against exact RHCR at a large size: part ``fidelity_large`` of
:mod:`benchmarks.bench_screen`.

Fidelity at a large size (``BENCH_SCREEN_PARTS=fidelity_large``, not in the default set: about
2 CPU-hours at 101x102): every layout JSON of ``BENCH_SCREEN_LAYOUTS`` (a directory, e.g. an
evaluation's ``layouts/``; ``*_unrepaired.json`` skipped) with ``BENCH_SCREEN_LARGE_AGENTS``
agents (default 1000,1400), seeds ``BENCH_SCREEN_LARGE_SEEDS`` (default 0,1), T=1,000, in the
domain ``BENCH_SCREEN_LARGE_DOMAIN`` (default warehouse_even; the screen uses that domain's
crowding threshold): exact RHCR (threads: all CPUs; cached in ``BENCH_SCREEN_RHCR_CACHE`` if
set) against the screen, run by run and by each layout's majority verdict; where both flow,
the screen's throughput (raw, scaled by 1.3 and the free-flow estimate) against RHCR's.
"""

from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np

from benchmarks.screen_common import CONGESTED_SCALE, EFFICIENCY
from nca_qd.calibration.layout_set import SCENARIO
from nca_qd.io import load_map
from nca_qd.sim.free_flow import free_flow_throughput
from nca_qd.sim.scenario import build_scenario


def fidelity_large() -> None:
    """Screen against exact RHCR at a large size, run by run and layout by layout (majority
    verdicts; where both flow, the screen's throughput estimates against RHCR's)."""
    from omegaconf import OmegaConf

    from experiments.cli import compose_config
    from nca_qd.sim.rhcr import simulate_many
    from nca_qd.sim.screen import crowd_mean_for, simulate_scenarios

    folder = os.environ.get("BENCH_SCREEN_LAYOUTS")
    if not folder or not Path(folder).is_dir():
        print("fidelity_large: set BENCH_SCREEN_LAYOUTS to a directory of layout JSON files")
        return
    files = sorted(f for f in Path(folder).glob("*.json") if not f.stem.endswith("_unrepaired"))
    layouts = [(f.stem, load_map(f).rows) for f in files]
    shapes = {(len(r), len(r[0])) for _, r in layouts}
    if len(shapes) != 1:
        print(f"fidelity_large: the layouts must share one size, got {sorted(shapes)}")
        return
    domain = os.environ.get("BENCH_SCREEN_LARGE_DOMAIN", SCENARIO)
    crowd = crowd_mean_for(OmegaConf.to_container(compose_config("run", [f"domain={domain}"]).domain))
    agents = [int(a) for a in os.environ.get("BENCH_SCREEN_LARGE_AGENTS", "1000,1400").split(",")]
    seeds = [int(s) for s in os.environ.get("BENCH_SCREEN_LARGE_SEEDS", "0,1").split(",")]
    steps = 1000
    cache = os.environ.get("BENCH_SCREEN_RHCR_CACHE")
    done = json.loads(Path(cache).read_text()) if cache and Path(cache).is_file() else {}
    ((h, w),) = shapes
    print(
        f"== fidelity at {h}x{w} ({domain}, crowding threshold {crowd}): {len(layouts)} layouts x "
        f"{agents} agents x seeds {seeds}, T={steps}"
    )
    agree, majority, ratios = [], [], {"raw": [], "scaled": [], "free_flow": []}
    for n in agents:
        scens = [build_scenario(r, domain, n_agents=n, source=name) for name, r in layouts]
        screened = simulate_scenarios(scens, n, steps, seeds, crowd_mean=crowd)
        for (name, rows), scen, sc in zip(layouts, scens, screened):
            key = f"{name}|{h}x{w}|{n}|{steps}" + ("" if domain == SCENARIO else f"|{domain}")
            known = done.get(key, {})
            if isinstance(known, list):  # the older cache: a list for seeds 0, 1, ...
                known = {str(i): run for i, run in enumerate(known)}
            missing = [s for s in seeds if str(s) not in known]
            if missing:  # RHCR for the seeds not cached yet
                more = simulate_many(rows, domain, n, steps, missing)
                known.update({str(s): [r.throughput, r.success, r.stop_time] for s, r in zip(missing, more)})
                done[key] = known
                if cache:
                    Path(cache).write_text(json.dumps(done))
            exact = [known[str(s)] for s in seeds]
            for (tp, ok, stop), r in zip(exact, sc):
                agree.append(bool(ok) == bool(r.success))
                print(
                    f"  {name:28s} {n:5d} agents  rhcr {'ok ' if ok else 'CON'} stop {stop:5d} "
                    f"tp {tp:6.2f} | screen {'ok ' if r.success else 'CON'} stop "
                    f"{r.stop_time:5d} tp {r.throughput:6.2f}"
                )
            ex_ok = np.array([e[1] for e in exact], bool)
            sc_ok = np.array([r.success for r in sc], bool)
            majority.append((ex_ok.mean() > 0.5) == (sc_ok.mean() > 0.5))
            if ex_ok.mean() > 0.5 and sc_ok.mean() > 0.5:  # both flow: the estimates against RHCR
                rhcr_tp = float(np.mean([e[0] for e in exact if e[1]]))
                raw = float(np.mean([r.throughput for r in sc if r.success]))
                flow = free_flow_throughput(scen, n)
                estimates = {"raw": raw, "scaled": CONGESTED_SCALE * raw, "free_flow": EFFICIENCY * flow}
                for kind, value in estimates.items():
                    ratios[kind].append(value / rhcr_tp)
                shares = ", ".join(f"{kind} x{value / rhcr_tp:.3f}" for kind, value in estimates.items())
                print(f"    both flow: RHCR {rhcr_tp:.2f}, screen {raw:.2f}; {shares} (free flow {flow:.2f})")
    print(
        json.dumps(
            {
                "size": f"{h}x{w}",
                "domain": domain,
                "runs": len(agree),
                "congestion_agreement_per_run": round(float(np.mean(agree)), 3),
                "layout_cases": len(majority),
                "congestion_agreement_layout_majority": round(float(np.mean(majority)), 3),
                "both_flow": len(ratios["raw"]),
                **{
                    f"throughput_ratio_{k}": [round(float(np.min(v)), 3), round(float(np.max(v)), 3)]
                    for k, v in ratios.items()
                    if v
                },
            }
        )
    )
