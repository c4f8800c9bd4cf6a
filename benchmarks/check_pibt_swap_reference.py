"""Side by side: this core's lifelong PIBT with swap (``planner="pibt_swap"``) against the
planner it re-implements, the PIBT with swap of its author's LaCAM3, Kei18/lacam3
(``lacam3/src/pibt.cpp``, ``PIBT::set_new_config`` with ``flg_swap``).

    git clone https://github.com/Kei18/lacam3 /tmp/lacam3      # outside this repository
    python -m benchmarks.check_pibt_swap_reference --lacam3 /tmp/lacam3 --agents 100,200 --seeds 0-4
    python -m benchmarks.check_pibt_swap_reference --lacam3 /tmp/lacam3 --replay

lacam3 solves one-shot instances; benchmarks/lacam3_lifelong/driver.cpp runs its PIBT class one
step per call under this repository's task model (the same start cells, goals, dwells,
priorities and congestion rule per seed as our core). It is compiled with g++ -O2 against the
given checkout into a cache folder outside the repository (``$XDG_CACHE_HOME`` or ``~/.cache``,
``nca_qd/lacam3_driver/``, one build per version of the sources); the maps are exported from the
layout files under results/ into a temporary folder. lacam3 is never copied here.

By default each planner breaks its ties its own way (lacam3: a random float per neighbour, from
its own generator), so runs are not paired step by step and only their throughputs are
compared: per map and number of agents, the mean ± standard error, the congested runs, the
relative difference, and whether that difference is within 2 % and within 2 standard errors of
the difference. ``--replay`` instead feeds lacam3's planner our candidate order (our neighbour
order, our Fisher-Yates with our random stream, a stable sort by distance), through the one
tie-breaker draw of its pibt.cpp (benchmarks/lacam3_lifelong/hook_pibt.cpp); nothing else of it
is replaced, so any difference in any agent's cell at any step is one in the PIBT-with-swap
logic. It prints one line per run and the count of runs identical at every step.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from nca_qd.evaluation.stats import mean_se_ci

ROOT = Path(__file__).resolve().parents[1]
DRIVER_DIR = ROOT / "benchmarks" / "lacam3_lifelong"
RNG_HPP = ROOT / "nca_qd" / "sim" / "rhcr" / "src" / "rng.hpp"  # the driver draws with the core's own stream
MAPS = {  # name: (layout file, scenario)
    "warehouse_even_human": (
        "results/warehouse_even_qd/cma_mae_a5_s0/evaluation/layouts/human_33x36.json",
        "warehouse_even",
    ),
    "warehouse_even_nca4472": (
        "results/warehouse_even_qd/cma_mae_a5_s0/evaluation/layouts/nca_c4472_33x36.json",
        "warehouse_even",
    ),
    "warehouse_uneven_human": (
        "results/warehouse_uneven_a5/evaluation/layouts/human_33x36.json",
        "warehouse_uneven",
    ),
    "warehouse_uneven_nca5930": (
        "results/warehouse_uneven_a5/evaluation/layouts/nca_c5930_33x36.json",
        "warehouse_uneven",
    ),
    "manufacturing_human": ("results/manufacturing_a5/evaluation/layouts/human_33x36.json", "manufacturing"),
    "manufacturing_nca4616": (
        "results/manufacturing_a5/evaluation/layouts/nca_c4616_33x36.json",
        "manufacturing",
    ),
}
LACAM_SOURCES = ("graph.cpp", "instance.cpp", "dist_table.cpp", "utils.cpp")
CXXFLAGS = ("-O2", "-std=c++17", "-pthread")
FIELDS = {"finished": int, "throughput": float, "congested": lambda s: s == "1", "stop_time": int}
COUNTERS = ("violations", "table_mismatch", "hook_errors", "top_failures")


class CheckError(RuntimeError):
    """A failure outside the comparison itself (the build, a driver run): one line, exit 2."""


def lacam3_sources(checkout: Path) -> Path | None:
    """The folder holding lacam3's include/ and src/ (the clone's lacam3/, or that folder)."""
    for src in (checkout / "lacam3", checkout):
        if (src / "src" / "pibt.cpp").is_file() and (src / "include" / "pibt.hpp").is_file():
            return src
    return None


def build(src: Path, hooked: bool) -> Path:
    """Compiles the driver against the checkout, once per version of the sources and compiler:
    the binary is kept in a cache folder named by their hash, outside the repository, so that
    nothing of lacam3 (source or binary) lands in the working tree."""
    if shutil.which("g++") is None:
        raise CheckError("g++ is not on PATH (the lacam3 driver is compiled with it)")
    ours = [DRIVER_DIR / "driver.cpp", RNG_HPP] + ([DRIVER_DIR / "hook_pibt.cpp"] if hooked else [])
    theirs = [src / "src" / f for f in (*LACAM_SOURCES, "pibt.cpp")] + sorted((src / "include").glob("*.hpp"))
    version = subprocess.run(["g++", "--version"], capture_output=True, text=True).stdout.splitlines()[0]
    digest = hashlib.sha256(f"{version} {CXXFLAGS} {hooked}".encode())
    for f in ours + theirs:
        digest.update(f.read_bytes())
    cache = Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache") / "nca_qd" / "lacam3_driver"
    binary = cache / digest.hexdigest()[:16] / ("lifelong_lacam3_hooked" if hooked else "lifelong_lacam3")
    if binary.is_file():
        return binary
    binary.parent.mkdir(parents=True, exist_ok=True)
    tmp = binary.with_name(f".{binary.name}.{os.getpid()}")
    units = [str(DRIVER_DIR / "driver.cpp")]
    units.append(str(DRIVER_DIR / "hook_pibt.cpp") if hooked else str(src / "src" / "pibt.cpp"))
    flags = [*CXXFLAGS, f"-I{src / 'include'}"] + (["-DHOOKED", f"-I{src / 'src'}"] if hooked else [])
    cmd = ["g++", *flags, *units, *(str(src / "src" / f) for f in LACAM_SOURCES), "-o", str(tmp)]
    print(f"building {binary} ...", file=sys.stderr, flush=True)
    p = subprocess.run(cmd, capture_output=True, text=True)
    if p.returncode != 0:
        tmp.unlink(missing_ok=True)
        last = [line for line in p.stderr.splitlines() if "error" in line][:1] or p.stderr.splitlines()[-1:]
        raise CheckError(f"building the lacam3 driver failed: {' '.join(last)}")
    os.replace(tmp, binary)
    return binary


def export(scen, prefix: Path) -> None:
    """Writes the scenario for the driver: ``<prefix>.scen`` (mask, goal classes with cells,
    weights and dwell, the class cycle) and ``<prefix>.map``, the mask as a MovingAI map, so
    that lacam3 builds its graph with its own loader (and its own neighbour order)."""
    h, w = scen.traversable.shape
    lines = [f"{h} {w}"] + ["".join("1" if x else "0" for x in row) for row in scen.traversable]
    lines.append(str(len(scen.classes)))
    for c in scen.classes:
        lines.append(f"{int(c.dwell)} {len(c.cells)}")
        lines += [f"{int(cell)} {float(wt)!r}" for cell, wt in zip(c.cells.tolist(), c.weights.tolist())]
    lines.append(f"{len(scen.cycle)} " + " ".join(str(int(x)) for x in scen.cycle))
    Path(f"{prefix}.scen").write_text("\n".join(lines) + "\n")
    grid = ["".join("." if x else "@" for x in row) for row in scen.traversable]
    Path(f"{prefix}.map").write_text(f"type octile\nheight {h}\nwidth {w}\nmap\n" + "\n".join(grid) + "\n")


def run_ours(scen, n: int, T: int, seed: int, paths: bool = False) -> dict:
    """One run of this core's pibt_swap; with ``paths``, its cells per step (flat indices)."""
    from nca_qd.sim import rhcr

    c0 = time.process_time()
    r = rhcr.simulate_scenario(scen, n, T, seed, replan=rhcr.REPLAN, planner="pibt_swap", record_paths=paths)
    out = {
        "throughput": r.throughput,
        "congested": r.congested,
        "stop_time": r.stop_time,
        "cpu_s": time.process_time() - c0,
    }
    if paths:
        p = np.asarray(r.paths).astype(np.int64)
        out["cells"] = (p[..., 0] * scen.traversable.shape[1] + p[..., 1]).reshape(-1, n)
    return out


def run_lacam3(binary: Path, prefix: Path, n: int, T: int, seed: int, trace: Path | None = None) -> dict:
    """One run of the driver (lacam3's ties, or with ``trace`` the replay); its figures and
    counters, and with ``trace`` its cells per step."""
    from nca_qd.sim import rhcr

    cmd = [str(binary), "--scen", f"{prefix}.scen", "--map", f"{prefix}.map", "--agents", str(n)]
    cmd += ["--T", str(T), "--seed", str(seed), "--replan", str(rhcr.REPLAN)]
    if trace is not None:
        cmd += ["--ties", "replay", "--trace", str(trace)]
    p = subprocess.run(cmd, capture_output=True, text=True)
    if p.returncode != 0:
        raise CheckError(
            f"the lacam3 driver failed ({prefix.name}, {n} agents, seed {seed}): {p.stderr.strip()}"
        )
    kv = dict(item.split("=", 1) for item in p.stdout.split())
    out = {k: conv(kv[k]) for k, conv in FIELDS.items()} | {k: int(kv[k]) for k in COUNTERS}
    out["cpu_s"] = float(kv["cpu_s"])
    if trace is not None:
        out["cells"] = np.fromfile(trace, dtype=np.int32).astype(np.int64).reshape(-1, n)
    return out


def table_row(name: str, n: int, ours: list[dict], theirs: list[dict]) -> str:
    """One markdown row: both planners' mean ± s.e. and congested runs, the relative difference
    (lacam3 against ours), and the two tolerances it is held to."""
    mo, so = mean_se_ci([r["throughput"] for r in ours])[:2]
    ml, sl = mean_se_ci([r["throughput"] for r in theirs])[:2]
    se_diff = float(np.hypot(so, sl))
    rel = 100 * (ml / mo - 1) if mo > 0 else float("nan")
    within_pct = "yes" if abs(rel) <= 2 else "no"
    within_se = "-" if np.isnan(se_diff) else ("yes" if abs(ml - mo) <= 2 * se_diff else "no")
    cong = lambda rs: f"{sum(r['congested'] for r in rs)}/{len(rs)}"  # noqa: E731
    pm = lambda m, se: f"{m:+.3f}" if np.isnan(se) else f"{m:+.3f} ± {se:.3f}"  # noqa: E731
    return (
        f"| {name} | {n} | {pm(mo, so)[1:]} | {cong(ours)} | {pm(ml, sl)[1:]} | {cong(theirs)} | "
        f"{rel:+.1f} % | {pm(ml - mo, se_diff)} | {within_pct} | {within_se} |"
    )


def free_driven(
    binary: Path, scens: dict, prefixes: dict, agents: list[int], seeds: list[int], T: int
) -> dict:
    """Both planners with their own ties; prints the table row by row, returns every run."""
    print(
        f"T = {T}, seeds {','.join(map(str, seeds))}: throughput mean ± s.e. over seeds; Δ: lacam3 vs ours\n"
    )
    print(
        "| map | agents | ours pibt_swap | congested | lacam3 swap | congested | Δ | "
        "difference ± s.e. | within 2 % | within 2 s.e. |"
    )
    print("|---|---|---|---|---|---|---|---|---|---|")
    runs: dict = {}
    for name, scen in scens.items():
        for n in agents:
            ours = [run_ours(scen, n, T, s) for s in seeds]
            theirs = [run_lacam3(binary, prefixes[name], n, T, s) for s in seeds]
            runs[name, n] = (ours, theirs)
            print(table_row(name, n, ours, theirs), flush=True)
    return runs


def replay(binary: Path, scens: dict, prefixes: dict, agents: list[int], seeds: list[int], T: int) -> int:
    """Lock-step: each of our runs against the driver fed our candidate order; prints one line
    per run, returns the number of runs identical at every step."""
    same = 0
    with tempfile.TemporaryDirectory(prefix="lacam3_trace_") as tmp:
        trace = Path(tmp) / "trace.bin"
        for name, scen in scens.items():
            for n in agents:
                for seed in seeds:
                    ours = run_ours(scen, n, T, seed, paths=True)
                    ref = run_lacam3(binary, prefixes[name], n, T, seed, trace=trace)
                    a, b = ours["cells"], ref["cells"]
                    m = min(len(a), len(b))
                    differ = np.flatnonzero((a[:m] != b[:m]).any(axis=1))
                    res: dict = {"map": name, "agents": n, "seed": seed}
                    if differ.size or len(a) != len(b):
                        step = int(differ[0]) if differ.size else m
                        agents_at = np.flatnonzero(a[step] != b[step])[:5].tolist() if step < m else []
                        res |= {"identical": False, "step": step, "differing_agents": agents_at}
                    else:
                        res |= {"identical": True, "steps": m - 1}
                        same += 1
                    res |= {k: ref[k] for k in COUNTERS if ref[k]}
                    print(json.dumps(res | {"stop_time": ours["stop_time"]}), flush=True)
    return same


def int_list(text: str) -> list[int]:
    """``0-4`` or ``0,3,7-9`` as a list; ValueError for anything else."""
    out: list[int] = []
    for part in text.split(","):
        a, dash, b = part.partition("-")
        if dash and not b:
            raise ValueError(part)
        out.extend(range(int(a), int(b or a) + 1))
    return out


def parse_args(argv: list[str] | None) -> argparse.Namespace:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--lacam3", required=True, help="a checkout of github.com/Kei18/lacam3")
    p.add_argument("--maps", default=",".join(MAPS), help=f"comma-separated, of {', '.join(MAPS)}")
    p.add_argument("--agents", default="100,200")
    p.add_argument("--seeds", default="0-4", help="e.g. 0-4 or 0,3,7-9")
    p.add_argument("--T", type=int, default=2000)
    p.add_argument("--replay", action="store_true", help="lock-step replay with our candidate order")
    return p.parse_args(argv)


def setup(args: argparse.Namespace, workdir: Path) -> tuple[Path, dict, dict, list[int], list[int]]:
    """Checks the arguments and the checkout, builds the driver, exports the maps; raises
    CheckError with one line for anything wrong."""
    from nca_qd.io import load_map
    from nca_qd.sim import rhcr
    from nca_qd.sim.scenario import build_scenario

    src = lacam3_sources(Path(args.lacam3))
    if src is None:
        raise CheckError(f"{args.lacam3} is not a checkout of Kei18/lacam3 (no lacam3/src/pibt.cpp)")
    try:
        agents, seeds = int_list(args.agents), int_list(args.seeds)
    except ValueError:
        raise CheckError(
            f"--agents {args.agents!r} / --seeds {args.seeds!r}: expected e.g. 100,200 / 0-4"
        ) from None
    if not agents or not seeds or min(agents) < 1 or min(seeds) < 0 or args.T < 1:
        raise CheckError("--agents, --T must be positive and --seeds non-negative")
    names = args.maps.split(",")
    unknown = sorted(set(names) - set(MAPS))
    if unknown:
        raise CheckError(f"unknown map(s) {', '.join(unknown)}")
    draws = (src / "src" / "pibt.cpp").read_text().count("get_random_float(")
    if args.replay and draws != 1:
        raise CheckError(
            f"{src}/src/pibt.cpp has {draws} tie-breaker draws; the replay hook expects one (1a269b7)"
        )
    scens, prefixes = {}, {}
    for name in names:
        path, scenario = MAPS[name]
        scens[name] = build_scenario(load_map(ROOT / path).rows, scenario, source=path)
        if max(agents) > scens[name].n_traversable:
            raise CheckError(
                f"{name} has {scens[name].n_traversable} free cells, fewer than {max(agents)} agents"
            )
    try:  # a core built before pibt_swap existed refuses the planner
        rhcr.simulate_scenario(next(iter(scens.values())), 1, 1, 0, planner="pibt_swap")
    except ValueError as e:
        raise CheckError(f"the installed core cannot run pibt_swap ({e}); rebuild it") from None
    for name in names:
        prefixes[name] = workdir / name
        export(scens[name], prefixes[name])
    return build(src, hooked=args.replay), scens, prefixes, agents, seeds


def main(argv: list[str] | None = None) -> int:
    args = parse_args(argv)
    try:
        with tempfile.TemporaryDirectory(prefix="lacam3_maps_") as tmp:
            binary, scens, prefixes, agents, seeds = setup(args, Path(tmp))
            if args.replay:
                same = replay(binary, scens, prefixes, agents, seeds, args.T)
                total = len(scens) * len(agents) * len(seeds)
                print(f"identical at every step: {same} of {total} runs")
                return 0 if same == total else 1
            runs = free_driven(binary, scens, prefixes, agents, seeds, args.T)
    except CheckError as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    driver = [r for _, theirs in runs.values() for r in theirs]
    bad = {k: sum(r[k] for r in driver) for k in COUNTERS}
    cpu = sum(r["cpu_s"] for pair in runs.values() for rs in pair for r in rs)
    print(f"\ndriver counters over {len(driver)} runs: {bad}; CPU {cpu:.1f} s")
    return 1 if bad["violations"] or bad["table_mismatch"] or bad["hook_errors"] else 0


if __name__ == "__main__":
    sys.exit(main())
