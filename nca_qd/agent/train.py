"""A training run of the maze agent on disk (``python -m experiments.train_agent``).

The run directory holds ``config.yaml``, ``checkpoint.msgpack`` (the whole
:class:`~nca_qd.agent.ppo.TrainState` plus counters, zlib-compressed: 0.8 MB with a level buffer of
1,000 66x66 levels; atomic, every ``checkpoint_every`` updates, at the end and on Ctrl-C: small
enough to commit as a training leg's snapshot), ``best.msgpack`` (the parameters with the best
held-out success) and ``metrics.csv``: per update ``update, env_steps, wall_seconds,
steps_per_second, mean_return, train_success`` (episodes of the training levels), the losses, the
level sampler's figures, every ``heldout.every_updates`` ``heldout_success`` / ``heldout_length`` on
the fixed held-out set (full horizon), and the device. Deterministic given ``seed``; a resumed run
continues from its checkpoint. A run started from a shipped agent keeps that agent's record
(``init_from.json``), so that shipping it extends the agent's lineage and training budget.
"""

from __future__ import annotations

import csv
import datetime
import io
import json
import logging
import time
from pathlib import Path
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
from omegaconf import DictConfig, OmegaConf

from nca_qd.agent.levels import Levels, border, nca_levels, random_levels, solve, solver_for
from nca_qd.agent.network import make_net, n_params
from nca_qd.agent.ppo import Trainer, TrainState, make_heldout_eval
from nca_qd.agent.shipped import META_FILE, WEIGHTS_FILE, save_agent
from nca_qd.errors import NcaQdError
from nca_qd.io import atomic_write_text, load_pytree, reference_maps_dir, save_pytree

log = logging.getLogger("nca_qd.agent")

CONFIG_FILE, METRICS_FILE = "config.yaml", "metrics.csv"
CHECKPOINT_FILE, BEST_FILE = "checkpoint.msgpack", "best.msgpack"
PRIOR_FILE = "init_from.json"  # the record of the shipped agent a run started from
COLUMNS = [
    "update",
    "env_steps",
    "wall_seconds",
    "steps_per_second",
    "mean_return",
    "train_success",
    "episodes",
    "loss",
    "policy_loss",
    "value_loss",
    "entropy",
    "replayed",
    "edited",
    "nca",
    "buffer_size",
    "buffer_score",
    "level_score",
    "heldout_success",
    "heldout_length",
    "device",
]


def validate(cfg: DictConfig) -> None:
    """Check the user-facing numbers; one :class:`NcaQdError` naming the field."""

    def number(path: str, kind=int, low=0.0, high=None, strict=True):
        v = OmegaConf.select(cfg, path)
        ok = isinstance(v, (int, float) if kind is float else int) and not isinstance(v, bool)
        if ok:
            ok = (v > low if strict else v >= low) and (high is None or v <= high)
        if not ok:
            rng = f"> {low}" if strict else f">= {low}"
            raise NcaQdError(
                f"{path} must be a{'n integer' if kind is int else ' number'} "
                f"{rng}{'' if high is None else f' and <= {high}'}, got {v!r}"
            )

    for p in (
        "total_env_steps",
        "n_envs",
        "horizon",
        "network.hidden",
        "network.conv_features",
        "network.dir_features",
        "network.head_hidden",
        "ppo.epochs",
        "ppo.minibatches",
        "levels.buffer_size",
        "levels.max_edits",
        "levels.tries",
        "heldout.episodes",
        "heldout.every_updates",
        "checkpoint_every",
    ):
        number(p)
    number("heldout.n_random", low=0, strict=False)
    number("levels.min_fill", low=0, strict=False)
    for p in ("ppo.lr", "ppo.clip", "ppo.max_grad_norm", "levels.temperature"):
        number(p, float)
    for p in ("ppo.gamma", "ppo.gae_lambda", "levels.replay_prob", "levels.edit_prob", "levels.staleness"):
        number(p, float, 0.0, 1.0, strict=False)
    for p in ("ppo.vf_coef", "ppo.ent_coef"):
        number(p, float, 0.0, strict=False)
    if not isinstance(cfg.seed, int) or isinstance(cfg.seed, bool):
        raise NcaQdError(f"seed must be an integer, got {cfg.seed!r}")
    if cfg.time_limit_s is not None:
        number("time_limit_s", float)
    for name in ("interior", "heldout.interior"):
        inter = OmegaConf.select(cfg, name)
        if name == "heldout.interior" and inter is None:
            continue
        if (
            inter is None
            or len(inter) != 2
            or not all(isinstance(v, int) and not isinstance(v, bool) and v >= 2 for v in inter)
        ):
            raise NcaQdError(f"{name} must be two integers >= 2, got {inter!r}")
    try:
        solver_for(OmegaConf.select(cfg, "levels.solver"), (1, 1))
    except ValueError as exc:
        raise NcaQdError(str(exc)) from None
    if OmegaConf.select(cfg, "heldout.n_nca") is not None:  # runs from before NCA held-out mazes lack it
        number("heldout.n_nca", low=0, strict=False)
        if OmegaConf.select(cfg, "heldout.nca_iters") is not None:
            number("heldout.nca_iters")
    if OmegaConf.select(cfg, "heldout.elites_from"):
        number("heldout.n_elites")
    if cfg.levels.method not in ("accel", "dr"):
        raise NcaQdError(f"levels.method must be accel or dr, got {cfg.levels.method!r}")
    for p in ("levels.density", "heldout.density"):
        d = OmegaConf.select(cfg, p)
        if (
            d is None
            or len(d) != 2
            or not all(isinstance(v, (int, float)) for v in d)
            or not 0 <= d[0] <= d[1] <= 1
        ):
            raise NcaQdError(f"{p} must be [low, high] with 0 <= low <= high <= 1, got {d!r}")
    if OmegaConf.select(cfg, "levels.nca_prob") is not None:  # runs from before NCA levels lack it
        number("levels.nca_prob", float, 0.0, 1.0, strict=False)
        number("levels.nca_iters")
        sig = cfg.levels.nca_sigma
        if (
            sig is None
            or len(sig) != 2
            or not all(isinstance(v, (int, float)) for v in sig)
            or not 0 <= sig[0] <= sig[1]
        ):
            raise NcaQdError(f"levels.nca_sigma must be [low, high] with 0 <= low <= high, got {sig!r}")
    if OmegaConf.select(cfg, "levels.min_interior") is not None:
        number("levels.min_interior", low=2, strict=False)
    if cfg.n_envs % cfg.ppo.minibatches:
        raise NcaQdError(f"n_envs={cfg.n_envs} is not divisible by ppo.minibatches={cfg.ppo.minibatches}")


def heldout_interior(cfg: DictConfig) -> tuple[int, int]:
    """The held-out mazes' interior: ``heldout.interior``, else the training ``interior`` (a
    larger held-out size selects the checkpoint that generalises to large mazes best)."""
    inter = OmegaConf.select(cfg, "heldout.interior") or cfg.interior
    return int(inter[0]), int(inter[1])


def heldout_nca_iters(cfg: DictConfig) -> int:
    """NCA iterations of the held-out NCA mazes: ``heldout.nca_iters``, else the maze domain's
    rule (C = 50 at 16x16 to C_eval = 200 at 64x64: linear in the side)."""
    n = OmegaConf.select(cfg, "heldout.nca_iters")
    if n is not None:
        return int(n)
    h, w = heldout_interior(cfg)
    return max(1, round(50 * (h * w) ** 0.5 / 16))


def archive_elite_levels(cfg: DictConfig, shape: tuple[int, int], solver: str) -> tuple[Levels, list[str]]:
    """``heldout.n_elites`` mazes grown at ``shape`` by generators of a maze QD run's result
    archive (``heldout.elites_from``): a seeded sample of its solvable elites, each run for
    :func:`heldout_nca_iters` iterations from the domain's seed; the unsolvable are left out."""
    from nca_qd.agent.transfer import load_maze_run
    from nca_qd.pipeline import generate, make_generator

    run_dir = Path(str(cfg.heldout.elites_from))
    domain, archive = load_maze_run(run_dir, "heldout.elites_from")
    objective = np.asarray(archive["objective"])
    solvable = np.flatnonzero(np.isfinite(objective) & (objective > 0))
    if solvable.size == 0:
        raise NcaQdError(f"heldout.elites_from: {run_dir} holds no elite with a solvable maze")
    rng = np.random.default_rng(int(cfg.heldout.seed))
    cells = np.sort(rng.choice(solvable, min(int(cfg.heldout.n_elites), solvable.size), replace=False))
    regions = generate(
        domain,
        make_generator(domain),
        archive["genotypes"][cells],
        shape=shape,
        n_iters=heldout_nca_iters(cfg),
    )
    layouts = border(jnp.asarray(regions, jnp.int32))
    length, start, goal = solve(layouts, solver, jax.random.PRNGKey(int(cfg.heldout.seed)))
    keep = np.flatnonzero(np.asarray(length) > 0)
    if keep.size < cells.size:
        log.info(
            "held-out elites: %d of %d grow unsolvable mazes at %s, left out",
            cells.size - keep.size,
            cells.size,
            shape,
        )
    pick = lambda a: jnp.asarray(a)[keep]  # noqa: E731
    return Levels(pick(layouts), pick(start), pick(goal)), [f"elite_c{int(c)}" for c in cells[keep]]


def heldout_levels(cfg: DictConfig) -> tuple[Levels, list[str]]:
    """The fixed held-out set: ``n_random`` random solvable mazes, ``n_nca`` mazes of random NCA
    generators (the QD search's kind of maze), the paper's map (bordered) and ``n_elites`` mazes of
    a QD run's elites (``elites_from``)."""
    from nca_qd.io import load_map

    hd = cfg.heldout
    h, w = heldout_interior(cfg)
    solver = solver_for(OmegaConf.select(cfg, "levels.solver"), (h, w))
    n_nca = int(OmegaConf.select(cfg, "heldout.n_nca") or 0)
    names = [f"random_{i}" for i in range(int(hd.n_random))] + [f"nca_{i}" for i in range(n_nca)]
    parts = []
    if int(hd.n_random) > 0:
        parts.append(
            random_levels(
                jax.random.PRNGKey(int(hd.seed)),
                int(hd.n_random),
                (h, w),
                tuple(hd.density),
                tries=8,
                solver=solver,
            )
        )
    if n_nca > 0:
        parts.append(
            nca_levels(
                jax.random.fold_in(jax.random.PRNGKey(int(hd.seed)), 2),
                n_nca,
                (h, w),
                tuple(cfg.levels.nca_sigma),
                heldout_nca_iters(cfg),
                tries=8,
                solver=solver,
            )
        )
    if hd.paper_map:
        path = reference_maps_dir() / str(hd.paper_map)
        if path.is_file():
            region = load_map(path, " X").to_array(" X")
            if region.shape == (h, w):
                layout = jnp.pad(jnp.asarray(region), 1, constant_values=1)
                length, start, goal = solve(layout)
                if int(length) > 0:
                    parts.append(Levels(layout[None], start[None], goal[None]))
                    names.append(path.stem)
            else:
                log.warning("held-out map %s is %s, not %s: left out", path, region.shape, (h, w))
        else:
            log.warning("held-out map %s not found: left out", path)
    if OmegaConf.select(cfg, "heldout.elites_from"):
        elites, elite_names = archive_elite_levels(cfg, (h, w), solver)
        parts.append(elites)
        names += elite_names
    if not parts:
        raise NcaQdError("the held-out set is empty (heldout.n_random=0 and no paper_map)")
    levels = jax.tree.map(lambda *xs: jnp.concatenate(xs, 0), *parts)
    return levels, names


def resolve_params_file(path: str | Path) -> Path:
    """``init_from``: a parameters file, or a run directory (its ``best.msgpack``)."""
    p = Path(path)
    p = p / BEST_FILE if p.is_dir() else p
    if not p.is_file():
        raise NcaQdError(f"init_from: {p} not found")
    return p


def init_from_steps(path: str | Path | None) -> int | None:
    """Environment steps behind ``init_from`` parameters: a shipped agent's total (its
    ``maze_agent.json``), or a run directory's best row (the last with the highest held-out
    success, as training keeps it); None when unknown."""
    prior = shipped_record(path)
    if prior is not None:
        return recorded_steps(prior)
    if not path or not (Path(path) / METRICS_FILE).is_file():
        return None
    with open(Path(path) / METRICS_FILE) as fh:
        rows = [r for r in csv.DictReader(fh) if r.get("heldout_success") not in (None, "")]
    if not rows:
        return None
    best = max(float(r["heldout_success"]) for r in rows)
    return int([r for r in rows if float(r["heldout_success"]) == best][-1]["env_steps"])


def shipped_record(path: str | Path | None) -> dict[str, Any] | None:
    """The ``maze_agent.json`` beside ``init_from`` when it names a shipped agent's weights (or
    its directory), else None: the record a new agent trained from it extends."""
    if not path:
        return None
    weights = Path(path) / WEIGHTS_FILE if Path(path).is_dir() else Path(path)
    meta = weights.parent / META_FILE
    if weights.name != WEIGHTS_FILE or not weights.is_file() or not meta.is_file():
        return None
    record: dict[str, Any] = json.loads(meta.read_text())
    return record


def recorded_steps(record: dict[str, Any]) -> int:
    """Environment steps behind a shipped agent, all its training runs together."""
    return int(record.get("total_env_steps", record.get("env_steps", 0)))


def lineage(prior: dict[str, Any] | None) -> list[dict[str, Any]]:
    """The training runs behind a shipped agent, oldest first (one entry if it kept no lineage)."""
    if prior is None:
        return []
    if prior.get("lineage"):
        return list(prior["lineage"])
    keep = ("env_steps", "updates", "wall_seconds", "heldout_success", "date", "device")
    return [{k: prior[k] for k in keep if k in prior}]


def device_name() -> str:
    """The accelerator (or CPU) training ran on, as JAX names it."""
    dev = jax.devices()[0]
    return f"{dev.platform}: {getattr(dev, 'device_kind', '?')} (x{jax.device_count()})"


class AgentRun:
    """Config + directory -> trained agent (see module doc)."""

    def __init__(self, cfg: DictConfig, run_dir: Path):
        validate(cfg)
        self.cfg, self.run_dir = cfg, Path(run_dir)
        self.net = make_net(cfg.network)
        self.trainer = Trainer(self.net, cfg)
        self.levels, self.level_names = heldout_levels(cfg)
        hh, hw = heldout_interior(cfg)
        self.eval_horizon = 2 * (hh + 2) * (hw + 2)
        self.evaluate = make_heldout_eval(self.net, self.levels, int(cfg.heldout.episodes), self.eval_horizon)

    # --- disk -------------------------------------------------------------------------------
    def _template(self) -> dict[str, Any]:
        return {
            "state": self.trainer.init(jax.random.PRNGKey(int(self.cfg.seed))),
            "wall_seconds": np.float64(0),
            "best_success": np.float64(-1),
            "best_update": np.int64(0),
        }

    def save(self, tree: dict[str, Any], rows: list[dict[str, Any]]) -> None:
        self.run_dir.mkdir(parents=True, exist_ok=True)
        atomic_write_text(self.run_dir / CONFIG_FILE, OmegaConf.to_yaml(self.cfg))
        buf = io.StringIO()
        writer = csv.DictWriter(buf, fieldnames=COLUMNS)
        writer.writeheader()
        writer.writerows(rows)
        atomic_write_text(self.run_dir / METRICS_FILE, buf.getvalue())
        save_pytree(self.run_dir / CHECKPOINT_FILE, tree, compress=True)  # 18 MB -> 0.8 MB at 64x64

    def load(self) -> tuple[dict[str, Any], list[dict[str, Any]]]:
        path = self.run_dir / CHECKPOINT_FILE
        if not path.is_file():
            raise NcaQdError(f"{self.run_dir}: no checkpoint to resume from ({CHECKPOINT_FILE} missing)")
        tree = load_pytree(path, self._template())
        upto = int(tree["state"].update)
        rows = []
        if (self.run_dir / METRICS_FILE).is_file():
            with open(self.run_dir / METRICS_FILE) as fh:
                rows = [r for r in csv.DictReader(fh) if int(r["update"]) <= upto]
        return tree, rows

    def best_params(self) -> Any:
        path = self.run_dir / BEST_FILE
        template = self._template()["state"].params
        if not path.is_file():
            raise NcaQdError(f"{self.run_dir}: no {BEST_FILE} yet (no held-out evaluation done)")
        return load_pytree(path, template)

    # --- training ---------------------------------------------------------------------------
    def heldout(self, params, update: int) -> tuple[float, float]:
        key = jax.random.fold_in(jax.random.PRNGKey(int(self.cfg.heldout.seed)), 1)
        reached, lengths = jax.device_get(self.evaluate(params, key))
        return float(np.mean(reached)), float(np.mean(lengths))

    def run(self, resume: bool = False) -> dict[str, Any]:
        """Train until ``total_env_steps`` (or ``time_limit_s``); returns the final tree."""
        from tqdm import tqdm

        cfg, tr = self.cfg, self.trainer
        if resume:
            tree, rows = self.load()
        else:
            tree, rows = self._template(), []
            if cfg.get("init_from"):
                params = load_pytree(resolve_params_file(cfg.init_from), tree["state"].params)
                tree["state"] = tree["state"]._replace(params=params, opt_state=self.trainer.tx.init(params))
                log.info("parameters initialised from %s", cfg.init_from)
                prior = shipped_record(cfg.init_from)
                if prior is not None:  # kept: the shipped files may be replaced before this run ships
                    self.run_dir.mkdir(parents=True, exist_ok=True)
                    atomic_write_text(self.run_dir / PRIOR_FILE, json.dumps(prior, indent=1) + "\n")
        state: TrainState = tree["state"]
        spu = tr.steps_per_update
        n_updates = -(-int(cfg.total_env_steps) // spu)
        done = int(state.update)
        if resume and done >= n_updates:
            log.info("nothing to train: %d of %d updates done", done, n_updates)
            return tree
        log.info(
            "maze agent: %d parameters, %d envs x %d steps per update, %d of %d updates done",
            n_params(state.params),
            tr.n_envs,
            tr.horizon,
            done,
            n_updates,
        )
        device = device_name()
        t_session = time.perf_counter()
        wall0 = float(tree["wall_seconds"])
        bar = tqdm(
            total=n_updates * spu,
            initial=done * spu,
            unit="step",
            unit_scale=True,
            disable=not cfg.progress,
            dynamic_ncols=True,
        )
        last_ckpt = done
        try:
            while int(state.update) < n_updates:
                if cfg.time_limit_s is not None and time.perf_counter() - t_session > cfg.time_limit_s:
                    log.info("time limit reached after %d updates", int(state.update))
                    break
                t0 = time.perf_counter()
                state, m = tr.update(state)
                m = jax.device_get(m)
                dt = time.perf_counter() - t0
                u = int(state.update)
                row = {
                    "update": u,
                    "env_steps": u * spu,
                    "steps_per_second": round(spu / dt, 1),
                    **{k: round(float(v), 6) for k, v in m.items()},
                    "heldout_success": "",
                    "heldout_length": "",
                    "device": device,
                }
                if u % int(cfg.heldout.every_updates) == 0 or u == n_updates:
                    succ, length = self.heldout(state.params, u)
                    row["heldout_success"], row["heldout_length"] = round(succ, 4), round(length, 2)
                    if succ >= float(tree["best_success"]):
                        tree["best_success"], tree["best_update"] = np.float64(succ), np.int64(u)
                        save_pytree(self.run_dir / BEST_FILE, state.params)
                    bar.set_postfix(heldout=f"{succ:.2f}", refresh=False)
                    log.info(
                        "update %d: env steps %d, held-out success %.3f (mean length %.1f), "
                        "train success %.3f",
                        u,
                        u * spu,
                        succ,
                        length,
                        m["train_success"],
                    )
                row["wall_seconds"] = round(wall0 + time.perf_counter() - t_session, 1)
                rows.append(row)
                bar.update(spu)
                tree["state"] = state
                tree["wall_seconds"] = np.float64(row["wall_seconds"])
                if u - last_ckpt >= int(cfg.checkpoint_every):
                    self.save(tree, rows)
                    last_ckpt = u
        except KeyboardInterrupt:
            self.save(tree, rows)
            bar.close()
            raise
        bar.close()
        if not (self.run_dir / BEST_FILE).is_file():
            succ, _ = self.heldout(state.params, int(state.update))
            tree["best_success"], tree["best_update"] = np.float64(succ), state.update
            save_pytree(self.run_dir / BEST_FILE, state.params)
        self.save(tree, rows)
        return tree

    def ship(self, tree: dict[str, Any], directory: str | Path | None = None) -> Path:
        """Write the best parameters and how they were trained as the shipped agent."""
        rows = []
        if (self.run_dir / METRICS_FILE).is_file():
            with open(self.run_dir / METRICS_FILE) as fh:
                rows = list(csv.DictReader(fh))
        best_u = int(tree["best_update"])
        at_best = next((r for r in rows if int(r["update"]) == best_u), None)
        curve = [
            {"env_steps": int(r["env_steps"]), "heldout_success": float(r["heldout_success"])}
            for r in rows
            if r.get("heldout_success") not in (None, "")
        ]
        sps = [float(r["steps_per_second"]) for r in rows if r.get("steps_per_second")]
        prior_file = self.run_dir / PRIOR_FILE
        prior = json.loads(prior_file.read_text()) if prior_file.is_file() else None
        prior = prior if prior is not None else shipped_record(self.cfg.get("init_from"))
        cfg, wall = self.cfg, float(at_best["wall_seconds"]) if at_best else float(tree["wall_seconds"])
        this_run = {
            "run": self.run_dir.name,
            "init_from": cfg.get("init_from"),
            "env_steps": best_u * self.trainer.steps_per_update,
            "updates": best_u,
            "wall_seconds": wall,
            "heldout_success": float(tree["best_success"]),
            "levels": f"interior {list(cfg.interior)} (new levels from {cfg.levels.min_interior}), "
            f"horizon {cfg.horizon}, {cfg.n_envs} envs; held out: {len(self.level_names)} mazes, "
            f"interior {list(heldout_interior(cfg))}",
            "device": "; ".join(
                sorted({r["device"] for r in rows if r.get("device") and int(r["update"]) <= best_u})
            )
            or "not recorded",
            "median_steps_per_second": float(np.median(sps)) if sps else None,
        }
        runs = [*lineage(prior), this_run]
        meta = {
            "network": OmegaConf.to_container(self.cfg.network),
            "n_params": n_params(self.best_params()),
            "trained_with": "python -m experiments.train_agent",
            "config": OmegaConf.to_container(self.cfg),
            **{k: this_run[k] for k in ("env_steps", "init_from", "updates", "wall_seconds")},
            "init_from_env_steps": (
                recorded_steps(prior) if prior is not None else init_from_steps(cfg.get("init_from"))
            ),
            "env_steps_run": int(tree["state"].update) * self.trainer.steps_per_update,
            "wall_seconds_run": float(tree["wall_seconds"]),
            **{k: this_run[k] for k in ("median_steps_per_second", "heldout_success")},
            "heldout": {
                "mazes": len(self.level_names),
                "names": self.level_names[-1:],
                "episodes": int(self.cfg.heldout.episodes),
                "horizon": self.eval_horizon,
            },
            "heldout_curve": curve,
            "device": this_run["device"],
            "lineage": runs,
            "total_env_steps": int(sum(int(r.get("env_steps", 0)) for r in runs)),
            "total_wall_seconds": round(sum(float(r.get("wall_seconds", 0)) for r in runs), 1),
            "date": datetime.datetime.now(datetime.UTC).isoformat(timespec="seconds"),
        }
        return save_agent(self.best_params(), meta, directory)
