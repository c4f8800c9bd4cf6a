"""The paper's maze transfer experiment (§5.2): an agent trained at 18x18 on NCA mazes of any size.

Cases (one result dict each, see :func:`run_transfer`):

* ``paper_nca_<S>``: the paper's NCA mazes (reference maps, interiors bordered here);
* ``own_nca_<S>``: this project's best maze generator (a QD run directory) generating at the
  training size (C) and at the evaluation size (C_eval), with the run's own domain settings;
* ``baseline_<S>``: random mazes of the large size with the reference maze's interior wall count
  and a start-goal path within ``path_ratio`` of its length (:func:`sample_baseline`).

Start and goal are the domain's (ends of the longest shortest path); the horizon is
``horizon_factor`` x tiles. A single maze reports the success rate over its episodes and the
binomial standard error; the baseline the mean over mazes of their success rates and the standard
error of that mean.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from nca_qd.domains.maze import horizon_for, longest_shortest_path, run_agent, solve_start_goal
from nca_qd.errors import NcaQdError
from nca_qd.io import load_map, reference_maps_dir
from nca_qd.sim import maze_agent as ma

log = logging.getLogger("nca_qd.maze_transfer")
TILES = " X"
PALETTE = {" ": "#000000", "X": "#808080"}


def bordered(interior: np.ndarray) -> np.ndarray:
    return np.pad(np.asarray(interior, np.int32), 1, constant_values=ma.WALL)


def load_interior(rel: str) -> np.ndarray:
    """A maze interior from the reference maps directory (or an absolute / relative path)."""
    path = Path(rel)
    if not path.is_file():
        path = reference_maps_dir() / rel
    return load_map(path, TILES).to_array(TILES)


def size_name(layout: np.ndarray) -> str:
    return f"{layout.shape[0]}x{layout.shape[1]}"


def draw_path(out: Path, layout: np.ndarray, start, goal, path: np.ndarray | None, title: str) -> None:
    """The maze with episode 0's path (blue), start (yellow triangle) and goal (green square)."""
    import matplotlib.pyplot as plt

    from nca_qd.viz import draw_layout, save_figure

    h, w = layout.shape
    size = max(3.0, min(10.0, 0.14 * max(h, w)))
    fig, ax = plt.subplots(figsize=(size, size))
    draw_layout(ax, layout, TILES, PALETTE, title)
    if path is not None and len(path) > 1:
        ax.plot(path[:, 1], path[:, 0], color="#3a7bd5", linewidth=1.2, alpha=0.8)
    ms = max(3.0, 120.0 / max(h, w))
    ax.plot([start[1]], [start[0]], marker="^", color="#ffd400", markersize=ms, linestyle="none")
    ax.plot([goal[1]], [goal[0]], marker="s", color="#2ca02c", markersize=ms, linestyle="none")
    save_figure(fig, out)


def case_horizon(shape: tuple[int, int], cfg: Mapping[str, Any]) -> int:
    """``horizon_factor`` x tiles, capped by ``max_horizon`` when set."""
    horizon = horizon_for(shape, int(cfg["horizon_factor"]))
    cap = cfg.get("max_horizon")
    return min(horizon, int(cap)) if cap else horizon


def agent_weights(cfg: Mapping[str, Any]) -> str | None:
    """``agent_weights`` of the configuration: a directory of learned parameters, or None."""
    w = cfg.get("agent_weights")
    return None if w in (None, "") else str(w)


def single_case(
    case: str, layout: np.ndarray, cfg: Mapping[str, Any], key: jax.Array, out: Path | None
) -> dict[str, Any]:
    """Success rate of the agent on one bordered maze (and its PNG)."""
    start, goal, length = solve_start_goal(layout)
    episodes = int(cfg["episodes"])
    horizon = case_horizon(layout.shape, cfg)
    res = {
        "case": case,
        "episodes": episodes,
        "success_rate": 0.0,
        "stderr": 0.0,
        "agent": str(cfg["agent"]),
        **({"agent_weights": agent_weights(cfg)} if agent_weights(cfg) else {}),
        "size": size_name(layout),
        "walls": int((layout[1:-1, 1:-1] == ma.WALL).sum()),
        "path_length": length,
        "horizon": horizon,
    }
    if length == 0:
        log.warning("%s: the maze has no start-goal path; success 0 without simulation", case)
        res["note"] = "unsolvable maze"
        return res
    run = run_agent(
        layout,
        start,
        goal,
        key,
        kind=str(cfg["agent"]),
        episodes=episodes,
        horizon=horizon,
        record_path=out is not None and cfg.get("pictures", True),
        weights=agent_weights(cfg),
    )
    p = float(np.mean(run.reached))
    res.update(
        success_rate=p,
        stderr=math.sqrt(p * (1 - p) / episodes),
        mean_episode_length=float(np.mean(run.lengths)),
    )
    if run.path is not None:
        draw_path(
            out / f"{case}.png",
            layout,
            start,
            goal,
            run.path,
            f"{case}: success {p:.2f} ({episodes} episodes), path {length}",
        )
    return res


def sample_baseline(
    rng: np.random.Generator,
    interior_shape: tuple[int, int],
    n_walls: int,
    target: int,
    ratio: tuple[float, float],
    n: int,
    batch: int,
    max_tries: int,
    progress: bool = False,
) -> tuple[list[tuple[np.ndarray, np.ndarray, np.ndarray, int]], int]:
    """Rejection sampling of ``n`` random bordered mazes: exactly ``n_walls`` walls placed
    uniformly at random in the interior, longest shortest path in ``[ratio[0], ratio[1]] x target``.
    Returns ``(mazes, tries)``; at most ``max_tries`` candidates, solved ``batch`` at a time."""
    from tqdm import tqdm

    h, w = interior_shape
    lo, hi = ratio[0] * target, ratio[1] * target
    solve = jax.jit(lambda free: longest_shortest_path(free))
    found, tries = [], 0
    bar = tqdm(total=n, desc="baseline mazes", disable=not progress, leave=False)
    while len(found) < n and tries < max_tries:
        b = min(batch, max_tries - tries)
        cand = np.zeros((batch, h * w), np.int32)
        for i in range(b):
            cand[i, rng.choice(h * w, n_walls, replace=False)] = ma.WALL
        layouts = np.pad(cand.reshape(batch, h, w), ((0, 0), (1, 1), (1, 1)), constant_values=ma.WALL)
        length, start, goal = jax.device_get(solve(jnp.asarray(layouts == ma.EMPTY)))
        tries += b
        for i in range(b):
            if lo <= length[i] <= hi and len(found) < n:
                found.append((layouts[i], start[i], goal[i], int(length[i])))
                bar.update(1)
    bar.close()
    return found, tries


def load_baseline_cache(path, setting: dict[str, Any]):
    """Baseline mazes saved by :func:`save_baseline_cache` for exactly this ``setting``, else None."""
    import json

    if not path or not Path(path).is_file():
        return None
    with np.load(path) as data:
        if json.loads(str(data["setting"])) != setting:
            log.info("baseline cache %s is for another setting: sampling again", path)
            return None
        mazes = [
            (data["layouts"][i], data["starts"][i], data["goals"][i], int(data["lengths"][i]))
            for i in range(data["layouts"].shape[0])
        ]
        return mazes, int(data["tries"])


def save_baseline_cache(path, setting: dict[str, Any], mazes, tries: int) -> None:
    """Keep the sampled baseline mazes (sampling is the slow part; the draw is deterministic
    given the setting, so a cache only saves time)."""
    import json

    from nca_qd.io import save_npz

    if not path or not mazes:
        return
    save_npz(
        path,
        {
            "setting": np.array(json.dumps(setting, sort_keys=True)),
            "layouts": np.stack([m[0] for m in mazes]),
            "starts": np.stack([m[1] for m in mazes]),
            "goals": np.stack([m[2] for m in mazes]),
            "lengths": np.array([m[3] for m in mazes]),
            "tries": np.array(tries),
        },
    )


def baseline_case(
    case: str,
    reference: np.ndarray,
    cfg: Mapping[str, Any],
    key: jax.Array,
    rng: np.random.Generator,
    out: Path | None,
) -> dict[str, Any]:
    """Mean success over random mazes like ``reference`` (bordered), see :func:`sample_baseline`."""
    bc = cfg["baseline"]
    _, _, target = solve_start_goal(reference)
    n_walls = int((reference[1:-1, 1:-1] == ma.WALL).sum())
    ratio = tuple(float(v) for v in bc["path_ratio"])
    setting = {
        "seed": int(cfg["seed"]),
        "n_walls": n_walls,
        "target": int(target),
        "ratio": list(ratio),
        "n_mazes": int(bc["n_mazes"]),
        "batch": int(bc["batch"]),
        "max_tries": int(bc["max_tries"]),
        "shape": list(reference.shape),
    }
    cached = load_baseline_cache(bc.get("cache"), setting)
    if cached is not None:
        mazes, tries = cached
    else:
        mazes, tries = sample_baseline(
            rng,
            (reference.shape[0] - 2, reference.shape[1] - 2),
            n_walls,
            target,
            ratio,
            int(bc["n_mazes"]),
            int(bc["batch"]),
            int(bc["max_tries"]),
            bool(cfg.get("progress", False)),
        )
        save_baseline_cache(bc.get("cache"), setting, mazes, tries)
    episodes = int(bc["episodes"])
    res = {
        "case": case,
        "episodes": episodes * len(mazes),
        "success_rate": 0.0,
        "stderr": 0.0,
        "agent": str(cfg["agent"]),
        **({"agent_weights": agent_weights(cfg)} if agent_weights(cfg) else {}),
        "size": size_name(reference),
        "mazes": len(mazes),
        "episodes_per_maze": episodes,
        "walls": n_walls,
        "reference_path_length": target,
        "path_ratio": list(ratio),
        "candidates_drawn": tries,
    }
    if len(mazes) < int(bc["n_mazes"]):
        log.warning(
            "%s: only %d of %d mazes found in %d candidates", case, len(mazes), int(bc["n_mazes"]), tries
        )
    if not mazes:
        res["note"] = "no baseline maze found"
        return res
    horizon = case_horizon(reference.shape, cfg)
    weights = agent_weights(cfg)
    keys = jax.random.split(key, len(mazes))
    # One maze at a time through run_agent (same compiled rollout as the single-maze cases).
    runs = [
        run_agent(
            lay, s, g, keys[i], kind=str(cfg["agent"]), episodes=episodes, horizon=horizon, weights=weights
        )
        for i, (lay, s, g, _) in enumerate(mazes)
    ]
    per_maze = np.array([r.reached.mean() for r in runs])
    se = float(per_maze.std(ddof=1) / math.sqrt(len(per_maze))) if len(per_maze) > 1 else 0.0
    res.update(
        success_rate=float(per_maze.mean()),
        stderr=se,
        horizon=horizon,
        path_length_mean=float(np.mean([m[3] for m in mazes])),
        mean_episode_length=float(np.mean([r.lengths.mean() for r in runs])),
    )
    if out is not None and cfg.get("pictures", True):
        for i in range(min(int(bc["pictures"]), len(mazes))):
            lay, s, g, length = mazes[i]
            run = run_agent(
                lay,
                s,
                g,
                keys[i],
                kind=str(cfg["agent"]),
                episodes=episodes,
                horizon=horizon,
                record_path=True,
                weights=weights,
            )
            draw_path(
                out / f"{case}_{i}.png",
                lay,
                s,
                g,
                run.path,
                f"{case} #{i}: success {per_maze[i]:.2f}, path {length}",
            )
    return res


def longest_path_elite(domain, gen, archive: Mapping[str, np.ndarray], chunk: int = 1024) -> int | None:
    """Among the elites of the best objective (the maze's is binary: solvable), the one whose
    maze at the training size has the longest start-goal shortest path (ties: more walls) -- an
    intricate maze, the kind the paper shows, chosen without the agent. (The archive's first best
    cell is often an empty room, and the most walls a two-tile corridor: both say nothing about
    transfer.)"""
    from nca_qd.pipeline import generate

    objective = archive["objective"]
    occ = np.flatnonzero(np.isfinite(objective))
    if occ.size == 0:
        return None
    top = occ[objective[occ] == objective[occ].max()]
    length, walls = [], []
    for i in range(0, top.size, chunk):  # a full maze archive holds ~10^4 best elites
        mazes = np.asarray(
            domain.assemble(generate(domain, gen, archive["genotypes"][top[i : i + chunk]], "train"))
        )
        length.append(np.asarray(longest_shortest_path(jnp.asarray(mazes == ma.EMPTY))[0]))
        walls.append((mazes == ma.WALL).sum(axis=(1, 2)))
    return int(top[np.lexsort((-np.concatenate(walls), -np.concatenate(length)))[0]])


def load_maze_run(run_dir: str | Path, what: str = "") -> tuple[Any, dict[str, np.ndarray]]:
    """``(domain, result archive)`` of a maze QD run directory; anything else is one
    :class:`NcaQdError` (prefixed with ``what``, the setting that named the directory)."""
    from nca_qd.domains import make_domain
    from nca_qd.run_dir import load_archive, load_run_config

    prefix = f"{what}: " if what else ""
    try:
        cfg = load_run_config(Path(run_dir))
    except NcaQdError as exc:
        raise NcaQdError(f"{prefix}{exc}") from None
    if not str(cfg.domain.name).startswith("maze"):
        raise NcaQdError(f"{prefix}{run_dir} is a {cfg.domain.name!r} run, not a maze run")
    return make_domain(cfg.domain), load_archive(run_dir, "result")


def own_nca_layouts(run_dir: str | Path, elite: int | None) -> tuple[dict[str, np.ndarray], int]:
    """The run's chosen generator's bordered mazes at the training and evaluation sizes."""
    from nca_qd.pipeline import generate, make_generator

    domain, archive = load_maze_run(run_dir)
    gen = make_generator(domain)
    if elite is None:
        cell = longest_path_elite(domain, gen, archive)
        if cell is None:
            raise NcaQdError(f"{run_dir}: the archive is empty")
    else:
        cell = int(elite)
        if not (0 <= cell < archive["objective"].size) or not np.isfinite(archive["objective"][cell]):
            raise NcaQdError(f"{run_dir}: no elite in cell {cell}")
    out = {
        which: np.asarray(domain.assemble(generate(domain, gen, archive["genotypes"][[cell]], which)[0]))
        for which in ("train", "eval")
    }
    return out, cell


def run_transfer(cfg: Mapping[str, Any], out: Path | None, emit=None) -> list[dict[str, Any]]:
    """Every case in order; ``emit(result)`` is called as each one finishes."""
    ma.get_policy(str(cfg["agent"]), agent_weights(cfg))  # an unknown kind fails before any work
    results: list[dict[str, Any]] = []
    key = jax.random.PRNGKey(int(cfg["seed"]))
    rng = np.random.default_rng(int(cfg["seed"]))

    def done(res):
        results.append(res)
        if emit is not None:
            emit(res)

    small = bordered(load_interior(str(cfg["maps"]["small"])))
    large = bordered(load_interior(str(cfg["maps"]["large"])))
    for i, lay in enumerate((small, large)):
        done(single_case(f"paper_nca_{size_name(lay)}", lay, cfg, jax.random.fold_in(key, i), out))
    own = None
    if cfg.get("run_dir"):
        own, cell = own_nca_layouts(cfg["run_dir"], cfg.get("elite"))
        log.info("own NCA generator: cell %d of %s", cell, cfg["run_dir"])
        for i, which in enumerate(("train", "eval")):
            lay = own[which]
            res = single_case(f"own_nca_{size_name(lay)}", lay, cfg, jax.random.fold_in(key, 2 + i), out)
            res["cell"] = cell
            done(res)
    else:
        log.info("no run_dir given: own_nca cases skipped")
    reference = large
    if str(cfg["baseline"]["reference"]) == "own":
        if own is None:
            raise NcaQdError("baseline.reference=own needs run_dir=<maze QD run>")
        reference = own["eval"]
    elif str(cfg["baseline"]["reference"]) != "paper":
        raise NcaQdError(f"baseline.reference must be paper or own, got {cfg['baseline']['reference']!r}")
    if int(cfg["baseline"]["n_mazes"]) > 0:
        done(
            baseline_case(
                f"baseline_{size_name(reference)}", reference, cfg, jax.random.fold_in(key, 4), rng, out
            )
        )
    return results
