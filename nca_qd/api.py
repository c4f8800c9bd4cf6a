"""A trained generator in five lines: load one from a run directory, grow a layout at any size.

    from nca_qd import load_generator
    g = load_generator("results/warehouse_even_qd/cma_mae_a5_s0")  # the result archive's best
    layout = g.layout(rows=101, cols=102)                          # whole map, repaired
    print("\\n".join(g.rows(layout)))                               # the paper's tile letters

Sizes are of the whole map (a warehouse's fixed workstation columns included), not of the
region the NCA draws. The NCA runs C iterations at the training size, C_eval at the evaluation
size and, in between or beyond, C interpolated linearly in the map's side (as the evaluation
does). The repair is the run's own at S and S_eval; at other sizes a warehouse needs
``n_shelves`` (the paper fixes the shelf count per size).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from nca_qd.errors import NcaQdError


@dataclass
class Generator:
    """One elite generator of a run: its NCA parameters, the domain it was trained on, its cell."""

    run_dir: Path
    cell: int
    objective: float
    params: np.ndarray
    domain: Any
    cfg: Any
    _nca: Any

    @property
    def tiles(self) -> str:
        """Tile letters of the layouts (index i of a layout is ``tiles[i]``)."""
        return str(self.domain.layout_tiles)

    def full_shape(self, which: str = "train") -> tuple[int, int]:
        """The whole map's shape at the training (``train``) or evaluation size."""
        return _full_of(self.domain, self.domain.gen_shape(which))

    def n_iters(self, rows: int, cols: int) -> int:
        """NCA iterations at a whole-map size (module docstring)."""
        from nca_qd.evaluation.plan import interpolate_iters

        d = self.cfg.domain
        full = (int(rows), int(cols))
        s_train, s_eval = self.full_shape("train"), self.full_shape("eval")
        if full == tuple(s_train):
            return int(d.nca_iters.train)
        if full == tuple(s_eval):
            return int(d.nca_iters.eval)
        return interpolate_iters(full, s_train, s_eval, int(d.nca_iters.train), int(d.nca_iters.eval))

    def layout(
        self,
        rows: int | None = None,
        cols: int | None = None,
        *,
        repair: bool = True,
        n_iters: int | None = None,
        n_shelves: int | None = None,
        n_agents: int | None = None,
    ) -> np.ndarray:
        """The whole map ``[rows, cols]`` (tile indices) this generator grows; the training size
        when no size is given. ``repair=True`` returns the repaired layout (an
        :class:`~nca_qd.errors.NcaQdError` when the repair finds none)."""
        from nca_qd.pipeline import generate

        if rows is None and cols is None:
            rows, cols = self.full_shape("train")
        if rows is None or cols is None or int(rows) < 3 or int(cols) < 3:
            raise NcaQdError(f"give both rows and cols (at least 3 each), got rows={rows}, cols={cols}")
        full = (int(rows), int(cols))
        shape = _region_of(self.domain, full)
        n_iters = int(n_iters) if n_iters is not None else self.n_iters(*full)
        region = generate(self.domain, self._nca, self.params[None], shape=shape, n_iters=n_iters)[0]
        layout = np.asarray(self.domain.assemble(region), dtype=np.int32)
        if not repair or not _repairable(self.domain):
            return layout
        return self._repair(layout, full, n_shelves, n_agents)

    def _repair(self, layout, full, n_shelves, n_agents) -> np.ndarray:
        from nca_qd.repair import repair
        from nca_qd.scoring.jobs import repair_options

        d = self.cfg.domain
        s_eval = self.full_shape("eval")
        opts = repair_options(d, "eval" if full == s_eval else "train")
        if full not in (s_eval, self.full_shape("train")):
            opts.pop("n_shelves", None)
        if n_shelves is not None:
            opts["n_shelves"] = int(n_shelves)
        if n_agents is not None:
            opts["n_agents"] = int(n_agents)
        res = repair(d.name, layout, **opts)
        if res.layout is None:
            raise NcaQdError(f"the repair of the {full[0]}x{full[1]} layout found none ({res.status})")
        return res.layout

    def rows(self, layout: np.ndarray) -> list[str]:
        """A layout as rows of tile letters (the paper's map format)."""
        from nca_qd.io import array_to_rows

        return array_to_rows(np.asarray(layout, dtype=np.int32), self.tiles)


def load_generator(run_dir: str | Path, cell: int | str = "best") -> Generator:
    """The generator in ``cell`` of a run's result archive (``"best"``: the highest objective at
    the training size) — from the run's checkpoint or its portable snapshot."""
    from nca_qd.domains import make_domain
    from nca_qd.pipeline import make_generator
    from nca_qd.run_dir import load_archive, load_run_config

    cfg = load_run_config(run_dir)
    archive = load_archive(run_dir, "result")
    if cfg.get("algo", {}).get("name") == "dsage":
        raise NcaQdError(f"{run_dir}: a DSAGE run's archive holds layouts, not generators")
    objective = np.asarray(archive["objective"])
    if cell == "best":
        index = int(np.nanargmax(np.where(np.isfinite(objective), objective, -np.inf)))
    else:
        try:
            index = int(cell)
        except (TypeError, ValueError):
            raise NcaQdError(f"cell must be 'best' or an archive cell index, got {cell!r}") from None
        if not 0 <= index < objective.size or not np.isfinite(objective[index]):
            raise NcaQdError(f"{run_dir}: no elite in archive cell {index}")
    domain = make_domain(cfg.domain)
    params = np.asarray(archive["genotypes"][index], dtype=np.float32)
    return Generator(
        Path(run_dir), index, float(objective[index]), params, domain, cfg, make_generator(domain)
    )


def _repairable(domain) -> bool:
    from nca_qd.layouts import LAYOUTS

    return domain.name in LAYOUTS


def _full_of(domain, region: tuple[int, int]) -> tuple[int, int]:
    """Whole map of a generated region: a layout family's frame, or the maze's border."""
    from nca_qd.layouts import get_layout

    if _repairable(domain):
        return tuple(get_layout(domain.name).full_shape(tuple(region)))  # type: ignore[return-value]
    return int(region[0]) + 2, int(region[1]) + 2


def _region_of(domain, full: tuple[int, int]) -> tuple[int, int]:
    from nca_qd.layouts import get_layout

    if _repairable(domain):
        return get_layout(domain.name).region_shape(full)
    return full[0] - 2, full[1] - 2
