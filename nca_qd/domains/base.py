"""What the core needs to know about a domain.

A domain says which tiles exist, which region of the layout the NCA generates (and the fixed
frame around it), the initial (seed) environment for any size, and how a batch of generated
regions is scored (objective and measures). Sizes, NCA iterations, archive dimensions and other
numbers live in the domain's Hydra config (``experiments/conf/domain/<name>.yaml``); the class
holds the behaviour.

Layouts are ``int`` arrays of indices into an alphabet string. ``gen_tiles`` is the alphabet of
the generated region (what the NCA's channels mean); ``layout_tiles`` is the alphabet of the full
layout and starts with ``gen_tiles`` (so a generated index keeps its meaning in the layout), then
adds fixed-only tiles (the warehouse's workstation ``w``).
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from dataclasses import dataclass, field
from typing import Any, Callable, Mapping

import jax
import numpy as np


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
    extras: per-solution arrays or lists worth keeping (repaired layouts, timings, ...).
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


# A batched scorer: (regions [b, h, w] int, key, context) -> EvalBatch. ``context`` (a
# :class:`nca_qd.scoring.mapf.ScoringContext` or None) tells what the search knows, e.g. the
# result archive's elites; scorers that do not need it ignore it. A scorer may carry
# ``metric_names`` (scalars it reports in ``extras["metrics"]`` for the metrics CSV) and
# ``close()`` (release worker pools).
Evaluator = Callable[..., EvalBatch]


class Domain(ABC):
    """Behaviour of one domain; numbers come from its config (``cfg``)."""

    name: str
    gen_tiles: str
    layout_tiles: str
    # Tile character -> colour (matplotlib colour string) for pictures.
    palette: Mapping[str, str]

    def __init__(self, cfg: Mapping[str, Any]):
        self.cfg = cfg

    @property
    def n_tiles(self) -> int:
        """Number of NCA channels (tile types of the generated region)."""
        return len(self.gen_tiles)

    def gen_shape(self, which: str = "train") -> tuple[int, int]:
        """Shape of the generated region at the training (``train``) or evaluation size."""
        return tuple(self.cfg["size"][which])  # type: ignore[return-value]

    def nca_iters(self, which: str = "train") -> int:
        return int(self.cfg["nca_iters"][which])

    @abstractmethod
    def seed(self, shape: tuple[int, int]) -> np.ndarray:
        """Initial environment ``[h, w]`` (indices into ``gen_tiles``) of the generated region."""

    @abstractmethod
    def assemble(self, region: np.ndarray) -> np.ndarray:
        """Generated region(s) ``[..., h, w]`` -> full layout(s) in ``layout_tiles`` indices."""

    @abstractmethod
    def make_evaluator(self, run_cfg: Mapping[str, Any] | None = None) -> Evaluator:
        """A batched scorer for generated regions, built once (jit compile happens here).
        ``run_cfg`` is the whole run config (its ``eval`` block: evaluation backend, screening)."""

    @property
    def measure_names(self) -> list[str]:
        return list(self.cfg["measures"]["names"])
