"""Throughput against agent count for several layouts under one exact planner, resumable.

    python -m experiments.sweep domain=warehouse_even layouts=[human.json,nca.json] \\
        agents=[2500,5000,7500] seeds=10 planner=pibt T=5000 out=sweeps/league

Runs every (layout, agent count, seed) that ``out`` does not hold yet, as
``experiments.simulate`` would (same settings and defaults, simulate.yaml), and appends each
run's line to ``<out>/<layout stem>_<agents>.jsonl`` the moment it ends: Ctrl-C or SIGTERM
waits for the runs in flight and keeps them (a second one drops them and ends at once), and
the same command goes on from there (more seeds or more agent counts later extend the same
folder). ``sweep_config.yaml`` pins the folder's settings and each layout's digest; a later
call with other settings or a changed layout file is refused (one line, exit 2) rather than
mixing runs. Then writes, over every run the folder holds (not only this call's),
``summary.csv`` (per layout and agent count: runs, success rate, throughput mean ± s.e. over
all runs and over the runs that flowed, CPU seconds), ``summary.md`` and
``throughput_vs_agents.png``.
"""

from __future__ import annotations

import csv
import hashlib
import io
import json
import math
import os
import sys
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor, as_completed, wait
from pathlib import Path

import numpy as np
from omegaconf import DictConfig, OmegaConf

from experiments.cli import EXIT_INTERRUPTED, compose_config, main_guard, take_domain
from experiments.simulate import RunSettings, _int, exact_run
from nca_qd import memory
from nca_qd.errors import NcaQdError
from nca_qd.interrupts import deferred_interrupts
from nca_qd.io import atomic_write_text, load_map
from nca_qd.preload import preload
from nca_qd.sim.rhcr import PLANNER_KEYS, planner_title
from nca_qd.sim.scenario import build_scenario, tiles_for

# The settings a folder's runs share (anything else, e.g. threads, may change between calls).
PINNED = ("domain", "T", "simulator", "window", "replan", "time_limit_s", *PLANNER_KEYS, "screen_crowd_mean")


def _list(cfg: DictConfig, key: str) -> list:
    value = None if OmegaConf.is_missing(cfg, key) else cfg[key]
    if value is None or not OmegaConf.is_list(value) or len(value) == 0:
        raise NcaQdError(f"{key} must be a non-empty list, e.g. {key}=[a,b]")
    return list(value)


def read_records(path: Path) -> dict[int, dict]:
    """The runs recorded in one ``.jsonl`` file by seed (summary lines, as ``experiments.simulate``
    prints them, and a last line cut short by a kill are skipped)."""
    runs: dict[int, dict] = {}
    if not path.is_file():
        return runs
    for line in path.read_text().splitlines():
        try:
            rec = json.loads(line)
        except json.JSONDecodeError:
            continue
        if isinstance(rec, dict) and not rec.get("summary") and "seed" in rec:
            runs[int(rec["seed"])] = rec
    return runs


def _append(path: Path, record: dict) -> None:
    """One run's line, on disk before the next run starts."""
    line = json.dumps(record) + "\n"
    if path.is_file() and path.stat().st_size:
        with open(path, "rb") as f:
            f.seek(-1, os.SEEK_END)
            if f.read(1) != b"\n":  # a line cut short by a kill: leave it, start a new one
                line = "\n" + line
    with open(path, "a") as f:
        f.write(line)
        f.flush()
        os.fsync(f.fileno())


def _pin(out: Path, cfg: DictConfig, digests: dict[str, str]) -> None:
    """Write or check ``sweep_config.yaml``: the folder's settings and its layouts' digests."""
    settings = {k: (OmegaConf.to_container(cfg, resolve=True) or {}).get(k) for k in PINNED}
    path = out / "sweep_config.yaml"
    if path.is_file():
        old = OmegaConf.to_container(OmegaConf.load(path)) or {}
        assert isinstance(old, dict)
        for k, v in settings.items():
            if k in old.get("settings", {}) and old["settings"][k] != v:
                raise NcaQdError(
                    f"{out} holds runs with {k}={old['settings'][k]}, this call asks {k}={v}: "
                    "use another out= (or the same settings)"
                )
        for stem, digest in digests.items():
            had = old.get("layouts", {}).get(stem)
            if had is not None and had != digest:
                raise NcaQdError(f"{out} holds runs of another layout named {stem}: use another out=")
        digests = {**old.get("layouts", {}), **digests}
    atomic_write_text(path, OmegaConf.to_yaml(OmegaConf.create({"settings": settings, "layouts": digests})))


def by_tenth(tasks_per_step, T: int) -> list[float]:
    """Throughput in each tenth of the horizon (tasks finished there / its steps); a run stopped
    as congested finishes nothing after its stop. Their mean is the run's throughput; the last
    tenth shows a jam that grows without reaching the congestion rule's half of the agents by T,
    which the run's success and mean throughput hide."""
    done = np.zeros(T)
    tps = np.asarray(tasks_per_step, dtype=float)[:T]
    done[: tps.size] = tps
    return [round(float(x.sum()) / len(x), 4) for x in np.array_split(done, 10)]


def summarize_point(runs: list[dict]) -> dict:
    """One (layout, agents) point: success rate and throughput over all runs and flowing ones."""
    thr = np.array([r["throughput"] for r in runs], dtype=float)
    ok = np.array([bool(r["success"]) for r in runs])
    n = len(thr)
    se = float(thr.std(ddof=1) / math.sqrt(n)) if n > 1 else float("nan")
    flow = thr[ok]
    late = [r["throughput_by_tenth"][-1] for r in runs if "throughput_by_tenth" in r]
    return {
        "runs": n,
        "success_rate": float(ok.mean()),
        "throughput_mean": float(thr.mean()),
        "throughput_se": se,
        "ci95_low": float(thr.mean() - 1.96 * se) if n > 1 else float("nan"),
        "ci95_high": float(thr.mean() + 1.96 * se) if n > 1 else float("nan"),
        "throughput_flowing": float(flow.mean()) if flow.size else float("nan"),
        "throughput_last_tenth": float(np.mean(late)) if late else float("nan"),
        "cpu_seconds_mean": float(np.mean([r["cpu_seconds"] for r in runs])),
    }


def _fmt(x: float) -> str:
    return "—" if not math.isfinite(x) else f"{x:.2f}"


def write_summary(out: Path, rows: list[dict], planner: str) -> None:
    """``summary.csv``, ``summary.md`` (agents down, layouts across) and the picture."""
    keys = ["layout", "agents", *summarize_point([{"throughput": 0, "success": 1, "cpu_seconds": 0}])]
    buf = io.StringIO()
    w = csv.DictWriter(buf, fieldnames=keys, lineterminator="\n")
    w.writeheader()
    for r in rows:
        w.writerow({k: (round(v, 6) if isinstance(v, float) else v) for k, v in r.items() if k in keys})
    atomic_write_text(out / "summary.csv", buf.getvalue())
    labels = list(dict.fromkeys(r["layout"] for r in rows))
    counts = sorted({r["agents"] for r in rows})
    cell = {(r["layout"], r["agents"]): r for r in rows}
    lines = [
        f"Throughput (mean ± s.e. over all runs; a congested run counts the tasks it finished over T) "
        f"and how many runs flowed (ended without congestion); then the throughput of the horizon's last "
        f"tenth (mean over runs; a jam that grows without stopping a run shows there); "
        f"planner {planner_title(planner)}.",
        "",
        "| agents | " + " | ".join(labels) + " |",
        "|---" * (len(labels) + 1) + "|",
    ]
    for a in counts:
        parts = []
        for lab in labels:
            r = cell.get((lab, a))  # layouts may have been run at different counts
            if r is None:
                parts.append("not run")
                continue
            ok = round(r["success_rate"] * r["runs"])
            late = (
                ""
                if not math.isfinite(r["throughput_last_tenth"])
                else f"; last tenth {_fmt(r['throughput_last_tenth'])}"
            )
            parts.append(
                f"{_fmt(r['throughput_mean'])} ± {_fmt(r['throughput_se'])}, {ok} of {r['runs']} flow{late}"
            )
        lines.append(f"| {a:,} | " + " | ".join(parts) + " |")
    atomic_write_text(out / "summary.md", "\n".join(lines) + "\n")
    plot_points(out / "throughput_vs_agents.png", rows, planner)


def plot_points(path: Path, rows: list[dict], planner: str) -> None:
    """Per layout: the mean over the horizon with its 95 % interval (solid) and, where runs
    recorded it, the horizon's last tenth (dotted): a gap between them is a jam that grows."""
    import matplotlib.pyplot as plt

    from nca_qd.viz import save_figure

    fig, ax = plt.subplots(figsize=(6.4, 4.2))
    for i, lab in enumerate(dict.fromkeys(r["layout"] for r in rows)):
        pts = sorted((r for r in rows if r["layout"] == lab), key=lambda r: r["agents"])
        err = [1.96 * r["throughput_se"] if math.isfinite(r["throughput_se"]) else 0.0 for r in pts]
        x, y = [r["agents"] for r in pts], [r["throughput_mean"] for r in pts]
        ax.errorbar(x, y, yerr=err, color=f"C{i}", marker="s", ms=4, capsize=3, label=f"{lab}: mean over T")
        late = [(r["agents"], r["throughput_last_tenth"]) for r in pts]
        late = [(a, t) for a, t in late if math.isfinite(t)]
        if late:
            lx, ly = zip(*late)
            ax.plot(lx, ly, ":", color=f"C{i}", marker="v", ms=5, label=f"{lab}: last tenth of T")
    ax.set_xlabel("agents")
    ax.set_ylabel("throughput (tasks per step)")
    title = f"throughput against agents ({planner_title(planner)}); bars: 95 % interval over runs"
    ax.set_title(title, fontsize=8)
    ax.legend(fontsize=7, loc="best")
    ax.grid(alpha=0.3)
    save_figure(fig, path)


def main(argv: list[str]) -> int:
    argv, domain_override = take_domain(argv)
    cfg = compose_config("sweep", argv)
    if domain_override is not None:
        cfg.domain = domain_override
    if cfg.simulator != "rhcr":
        raise NcaQdError(
            f"a sweep runs the exact simulators (planner=rhcr|pibt|pibt_swap), not simulator={cfg.simulator}"
        )
    layouts = [Path(str(p)) for p in _list(cfg, "layouts")]
    counts = _list(cfg, "agents")
    if any(isinstance(a, bool) or not isinstance(a, int) or a < 1 for a in counts):
        raise NcaQdError(f"agents must be a list of positive integers, got {counts}")
    stems = [p.stem for p in layouts]
    if len(set(stems)) != len(stems):
        raise NcaQdError(f"layout file names must differ (they label the runs): {stems}")
    if OmegaConf.is_missing(cfg, "out") or not cfg.out:
        raise NcaQdError("give out=<folder>")
    n_runs, first = _int(cfg, "seeds", minimum=1), _int(cfg, "seed", minimum=0)
    domain = str(cfg.domain)
    tiles = tiles_for(domain)
    maps = {p.stem: load_map(p, tiles=tiles) for p in layouts}
    digests = {s: hashlib.sha256("\n".join(m.rows).encode()).hexdigest()[:16] for s, m in maps.items()}
    for a in counts:  # every setting checked before the first run
        RunSettings(OmegaConf.merge(cfg, {"agents": a}))
    out = Path(str(cfg.out))
    out.mkdir(parents=True, exist_ok=True)
    _pin(out, cfg, digests)
    seeds = list(range(first, first + n_runs))
    preload()  # a sweep takes hours: later edits to the tree cannot reach it
    try:
        _run_missing(cfg, out, maps, counts, seeds, domain)
    finally:  # an interrupted sweep's summary covers the runs it kept, as a finished one's does
        write_summary(out, folder_points(out), str(cfg.planner))
    return 0


def _run_missing(cfg: DictConfig, out: Path, maps: dict, counts: list, seeds: list[int], domain: str) -> None:
    """Every (layout, agents) point's missing seeds, each run kept the moment it ends."""
    for stem, mf in maps.items():
        for a in counts:
            path = out / f"{stem}_{a}.jsonl"
            todo = [s for s in seeds if s not in read_records(path)]
            if not todo:
                continue
            settings = RunSettings(OmegaConf.merge(cfg, {"agents": a}))
            scen = build_scenario(mf.rows, domain, n_agents=a, source=stem)
            parallel = max(1, min(settings.threads, len(todo)))
            memory.check(
                parallel * scen.simulation_bytes(a),
                f"{parallel} exact simulation(s) at once of the {scen.shape[0]}x{scen.shape[1]} map {stem}",
                hint="use fewer threads=, or a smaller map",
            )

            def keep(res, path=path, stem=stem, a=a, T=settings.T) -> None:
                record = {**res.summary(), "throughput_by_tenth": by_tenth(res.tasks_per_step, T)}
                _append(path, record)
                print(json.dumps({"layout": stem, "agents": a, **record}), flush=True)

            run_point(scen, settings, todo, parallel, keep)


def run_point(scen, settings: RunSettings, seeds: list[int], parallel: int, keep: Callable) -> None:
    """The runs of one point, ``parallel`` at a time, each kept the moment it ends. Stopped
    (Ctrl-C, SIGTERM), the runs not started are cancelled and the ones under way, which the
    core cannot abandon, are waited for and kept too, before the interruption goes on. A
    second interruption drops them: a run at 140x500 can take a quarter of an hour, and the
    threads running the core cannot be stopped, so the process ends there (what is on disk
    stands; the same command runs the dropped ones).

    Each run is kept once, whole: the interruption is held while ``keep`` writes and prints
    it (one that landed between the two left a run on disk that was never reported), and a
    run that had ended but was not kept yet when the interruption came is kept with the
    ones under way (it is neither cancellable nor under way)."""
    kept: set = set()

    def keep_once(f) -> None:
        with deferred_interrupts():
            if f not in kept:
                keep(f.result())
                kept.add(f)

    with ThreadPoolExecutor(max_workers=parallel) as pool:
        futures = [pool.submit(exact_run, scen, settings, seed) for seed in seeds]
        try:
            for f in as_completed(futures):
                keep_once(f)
        except KeyboardInterrupt:
            under_way = [f for f in futures if not f.cancel() and not f.done()]
            if under_way:
                print(
                    f"interrupted: waiting for the {len(under_way)} run(s) under way to keep them "
                    "(interrupt again to drop them)",
                    file=sys.stderr,
                    flush=True,
                )
            try:
                wait(under_way)
                for f in futures:
                    if f.done() and not f.cancelled() and f.exception() is None:
                        keep_once(f)
            except KeyboardInterrupt:
                print(
                    "interrupted again: the runs under way are dropped, the finished ones kept; "
                    "the same command runs the missing ones",
                    file=sys.stderr,
                    flush=True,
                )
                abandon(EXIT_INTERRUPTED)
            raise


def abandon(code: int) -> None:
    """End the process now, without joining the threads still inside the core."""
    os._exit(code)


def folder_points(out: Path) -> list[dict]:
    """Every (layout, agents) point the folder holds, all its recorded runs (they share the
    folder's settings): the summary of a sweep run in stages (more seeds, more counts later)."""
    pinned = OmegaConf.to_container(OmegaConf.load(out / "sweep_config.yaml")) or {}
    assert isinstance(pinned, dict)
    rows = []
    for stem in pinned.get("layouts", {}):
        counts = sorted(
            int(tail) for f in out.glob(f"{stem}_*.jsonl") if (tail := f.stem[len(stem) + 1 :]).isdigit()
        )
        for a in counts:
            runs = list(read_records(out / f"{stem}_{a}.jsonl").values())
            if runs:
                rows.append({"layout": stem, "agents": a, **summarize_point(runs)})
    return rows


if __name__ == "__main__":
    main_guard(main, on_interrupt="finished runs are kept; the same command runs the missing ones")()
