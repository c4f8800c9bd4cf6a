"""The types the pipeline's stages share, in one neutral module.

The QD loop (:mod:`nca_qd.qd`) searches over flat parameter vectors with *any* batched objective;
a domain (:mod:`nca_qd.domains`) scores generated layouts, the multi-agent domains through the
MAPF scorer (:mod:`nca_qd.scoring`). What passes between them is defined here, so that ``qd/``
depends on nothing domain- or MAPF-specific and a new evaluator or emitter only has to meet
these protocols:

- :class:`EvalBatch`: the scores of one batch (objective, measures, validity, extras).
- :class:`ScoringContext`: what the search tells a scorer about itself (the result archive's
  elites, the iteration).
- :class:`Evaluator`: ``(regions [b, h, w], key, context) -> EvalBatch``;
  :class:`HostEvaluator` adds what a host-side evaluator with worker pools and memory offers.
- :class:`Emitter`: ``init / ask / tell`` over the optimisation archive;
  :class:`CompactEmitter` adds the compact form its state takes in a checkpoint.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Protocol, runtime_checkable

import jax
import numpy as np

__all__ = [
    "CompactEmitter",
    "Emitter",
    "EvalBatch",
    "Evaluator",
    "HostEvaluator",
    "ScoringContext",
    "wants_ancillary",
]


def wants_ancillary(run_cfg: Any) -> bool:
    """Whether the run's algorithm learns an ancillary per-tile map from the simulation
    (``algo.ancillary``, DSAGE): then a scorer also returns ``extras["ancillary"] [b, h, w]``
    over the generated region (the maze agent's occupancy, the robots' tile usage)."""
    try:
        return bool(run_cfg["algo"]["ancillary"])
    except (KeyError, TypeError):
        return False


@dataclass
class EvalBatch:
    """Scores of a batch of generated regions.

    objective: ``[b]`` f_opt, what the optimisation archive ranks by.
    measures: ``[b, m]`` measure values (the archive's axes).
    result_objective: ``[b]`` f_res for the result archive (defaults to ``objective``).
    valid: ``[b]`` bool, False where scoring failed (e.g. repair found nothing); such solutions
        get the lowest objective and are not inserted in the archives.
    result_valid: ``[b]`` bool, which solutions the result archive may take (defaults to
        ``valid``; the multi-agent domains take only layouts with exact simulations).
    extras: per-solution arrays or lists worth keeping (repaired layouts, timings, ...);
        ``extras["metrics"]`` holds scalars for the metrics CSV.
    """

    objective: Any
    measures: Any
    result_objective: Any = None
    valid: Any = None
    result_valid: Any = None
    extras: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        if self.result_objective is None:
            self.result_objective = self.objective
        if self.valid is None:
            self.valid = np.ones(np.shape(self.objective), dtype=bool)
        if self.result_valid is None:
            self.result_valid = self.valid


# A pytree, so that jitted evaluators can return it.
jax.tree_util.register_dataclass(
    EvalBatch,
    data_fields=["objective", "measures", "result_objective", "valid", "result_valid", "extras"],
    meta_fields=[],
)


@dataclass
class ScoringContext:
    """What a scorer may know of the search when it scores a batch."""

    # measures [b, m] -> the result archive's elite objective in each one's cell (-inf: empty)
    result_elite: Callable[[np.ndarray], np.ndarray]
    # the iteration being scored (1 = the first): remembered results are stamped with it
    iteration: int = 0


class Evaluator(Protocol):
    """A batched scorer of generated regions; scorers that need no context ignore it."""

    def __call__(self, regions: Any, key: jax.Array, context: ScoringContext | None = None) -> EvalBatch: ...


@runtime_checkable
class HostEvaluator(Protocol):
    """A host-side evaluator (not jitted): it reports scalar metrics, keeps state across
    iterations that a resume must restore, and owns worker pools to release."""

    metric_names: tuple[str, ...]

    def __call__(self, regions: Any, key: jax.Array, context: ScoringContext | None = None) -> EvalBatch: ...

    def save_state(self, run_dir: str | Path) -> None: ...

    def restore_state(self, run_dir: str | Path, iteration: int) -> None: ...

    def close(self) -> None: ...


class Emitter(Protocol):
    """A QD algorithm's variation: functional state in and out, each call jittable."""

    batch_size: int

    def init(self, key: jax.Array) -> Any: ...

    def ask(self, state: Any, archive: Any, key: jax.Array) -> tuple[jax.Array, Any]: ...

    def tell(
        self, state: Any, archive: Any, solutions: jax.Array, fitness: jax.Array, info: Any, key: jax.Array
    ) -> Any: ...


@runtime_checkable
class CompactEmitter(Protocol):
    """An emitter whose state has a smaller checkpoint form (CMA-ES covariances)."""

    def compact_state(
        self, state: Any, rank: int, tolerance: float
    ) -> tuple[dict[str, np.ndarray], dict]: ...

    def expand_state(self, arrays: dict[str, np.ndarray], template: Any) -> Any: ...
