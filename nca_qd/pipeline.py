"""Generate -> score: the batched objective the QD loop searches over.

``make_objective(domain, generator)`` returns ``f(solutions [b, d], key) -> EvalBatch``: the
whole batch of NCA generators produces its environments in one vmapped call, then the domain
scores them (for the maze, one more jitted call; for domains with repair and simulation, the
domain's host-side pipeline).
"""

from __future__ import annotations

import jax
import numpy as np

from nca_qd.domains.base import Domain, EvalBatch
from nca_qd.nca import NCAGenerator


def make_generator(domain: Domain) -> NCAGenerator:
    return NCAGenerator(n_tiles=domain.n_tiles)


def generate(domain: Domain, generator: NCAGenerator, solutions, which: str = "train",
             shape: tuple[int, int] | None = None, n_iters: int | None = None) -> np.ndarray:
    """Generated regions ``[b, h, w]`` at the training or evaluation size (or any ``shape``)."""
    shape = shape or domain.gen_shape(which)
    n_iters = n_iters or domain.nca_iters(which)
    return np.asarray(generator.generate(solutions, domain.seed(shape), n_iters))


def make_objective(domain: Domain, generator: NCAGenerator):
    seed = domain.seed(domain.gen_shape("train"))
    n_iters = domain.nca_iters("train")
    evaluator = domain.make_evaluator()

    def objective(solutions: jax.Array, key: jax.Array) -> EvalBatch:
        regions = generator.generate(solutions, seed, n_iters)
        return evaluator(regions, key)

    return objective
