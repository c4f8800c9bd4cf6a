"""Generate -> score: the batched objective the QD loop searches over.

``make_objective(domain, generator, run_cfg)`` returns ``f(solutions [b, d], key, context)
-> EvalBatch``: the whole batch of NCA generators produces its environments in one vmapped
call, then the domain scores them (for the maze, one more jitted call; for domains with repair and
simulation, the
domain's host-side pipeline).
"""

from __future__ import annotations

import time

import jax
import jax.numpy as jnp
import numpy as np

from nca_qd import memory
from nca_qd.domains.base import Domain
from nca_qd.errors import NcaQdError
from nca_qd.interfaces import EvalBatch, HostEvaluator
from nca_qd.nca import NCAGenerator


class TileLayouts:
    """The identity "generator" of a direct search over layouts (DSAGE): a solution is the
    generated region itself, ``[d = H * W]`` tile indices (rounded and clipped to the tiles).
    It exists at the training size only: a layout cannot grow like an NCA's."""

    scalable = False

    def __init__(self, n_tiles: int, shape: tuple[int, int]):
        self.n_tiles, self.shape = int(n_tiles), (int(shape[0]), int(shape[1]))
        self.n_params = self.shape[0] * self.shape[1]

    def generate(self, solutions, seed, n_iters: int | None = None):
        """Solutions ``[b, d]`` -> regions ``[b, H, W]``; ``seed`` only fixes the shape asked for."""
        shape = tuple(np.shape(seed))
        if shape != self.shape:
            raise NcaQdError(
                f"a directly searched layout is {self.shape[0]}x{self.shape[1]}; it cannot be "
                f"generated at {shape[0]}x{shape[1]} (only NCA generators scale)"
            )
        x = jnp.clip(jnp.round(jnp.asarray(solutions)), 0, self.n_tiles - 1).astype(jnp.int32)
        return x.reshape((-1, *self.shape))


def make_generator(domain: Domain, algo: str | None = None) -> NCAGenerator | TileLayouts:
    """The NCA generator of the domain, or for ``algo="dsage"`` the direct tile layouts."""
    if algo == "dsage":
        return TileLayouts(domain.n_tiles, domain.gen_shape("train"))
    return NCAGenerator(n_tiles=domain.n_tiles)


def generate(
    domain: Domain,
    generator: NCAGenerator,
    solutions,
    which: str = "train",
    shape: tuple[int, int] | None = None,
    n_iters: int | None = None,
) -> np.ndarray:
    """Generated regions ``[b, h, w]`` at the training or evaluation size (or any ``shape``)."""
    shape = shape or domain.gen_shape(which)
    n_iters = n_iters or domain.nca_iters(which)
    batch = int(np.shape(solutions)[0])
    what = f"growing {batch} layout(s) of {shape[0]}x{shape[1]}"
    memory.check(memory.nca_bytes(batch, shape[0] * shape[1]), what)
    return np.asarray(generator.generate(solutions, domain.seed(shape), n_iters))


class Objective:
    """``objective(solutions [b, d], key, context=None) -> EvalBatch``: generate, then score.

    Carries the domain scorer's ``metric_names`` and adds ``generate_seconds`` to its metrics
    (host-side scorers); ``save_state`` / ``restore_state`` keep what the scorer remembers
    across a resume; ``close()`` releases the scorer's worker pools.
    """

    def __init__(self, domain: Domain, generator: NCAGenerator | TileLayouts, run_cfg=None):
        self.seed = domain.seed(domain.gen_shape("train"))
        self.n_iters = domain.nca_iters("train")
        self.generator = generator
        self.evaluator = domain.make_evaluator(run_cfg)
        self.metric_names = tuple(getattr(self.evaluator, "metric_names", ()))
        # NCA phases scored per generator (eval.phases; nca_qd/scoring/phases.py)
        cfg = getattr(self.evaluator, "cfg", None)
        self.phases = int(getattr(cfg, "phases", 1))
        if self.phases > 1 and not hasattr(generator, "trajectory"):
            raise NcaQdError(
                f"eval.phases={self.phases} needs an NCA generator (a direct search has one phase)"
            )

    def __call__(self, solutions: jax.Array, key: jax.Array, context=None) -> EvalBatch:
        t0 = time.perf_counter()
        if self.phases > 1:  # [b, P, H, W]: iterations C .. C + P - 1
            regions = self.generator.trajectory(solutions, self.seed, self.n_iters, self.phases - 1)[0]
        else:
            regions = self.generator.generate(solutions, self.seed, self.n_iters)
        if not self.metric_names:  # a jitted scorer: keep generation and scoring fused
            return self.evaluator(regions, key, context)
        regions = np.asarray(regions)  # waits for the device: the generation time is real
        t_gen = time.perf_counter() - t0
        ev = self.evaluator(regions, key, context)
        ev.extras.setdefault("metrics", {})["generate_seconds"] = t_gen
        return ev

    def save_state(self, run_dir) -> None:
        """Write what the scorer keeps between iterations (the MAPF scorer's memo), if any."""
        if isinstance(self.evaluator, HostEvaluator):
            self.evaluator.save_state(run_dir)

    def restore_state(self, run_dir, iteration: int) -> None:
        """Resume the scorer's own state as it was after ``iteration``, if it has one."""
        if isinstance(self.evaluator, HostEvaluator):
            self.evaluator.restore_state(run_dir, iteration)

    def close(self) -> None:
        if isinstance(self.evaluator, HostEvaluator):
            self.evaluator.close()


def make_objective(domain: Domain, generator: NCAGenerator, run_cfg=None) -> Objective:
    return Objective(domain, generator, run_cfg)
