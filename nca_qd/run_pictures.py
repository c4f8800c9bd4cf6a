"""The pictures of a QD run: both archives as heatmaps, the metric curves, and the best
elites' layouts at the training and the evaluation size (repaired too, where the domain
repairs).

Plain functions over what a run directory holds (its configuration, its archives as
:func:`nca_qd.run_dir.load_archive` views, ``metrics.csv``), so the same pictures come from a
finished :class:`nca_qd.experiment.Experiment`, from a run still in progress, or from a
committed snapshot on a fresh clone (``python -m experiments.render run=<dir> pictures=true``).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
from omegaconf import DictConfig

from nca_qd.domains import Domain, make_domain
from nca_qd.pipeline import generate, make_generator
from nca_qd.qd.loop import archive_spec
from nca_qd.run_dir import METRICS_FILE, archives_held, load_archive, select_elites


def write_run_pictures(
    run_dir: str | Path,
    cfg: DictConfig,
    archives: Mapping[str, Mapping[str, Any]] | None = None,
    domain: Domain | None = None,
    generator: Any = None,
    out_dir: str | Path | None = None,
) -> list[Path]:
    """Every picture of the run in ``run_dir``, written to ``out_dir`` (the run directory by
    default); returns the files written.

    ``archives`` maps ``result`` / ``opt`` to archive views (read from ``run_dir`` when not
    given: both, or the result archive alone from a run that ships only its elites record);
    ``domain`` and ``generator`` are built from ``cfg`` when not given."""
    run_dir = Path(run_dir)
    out = Path(out_dir) if out_dir is not None else run_dir
    out.mkdir(parents=True, exist_ok=True)
    if archives is None:
        archives = {which: load_archive(run_dir, which) for which in archives_held(run_dir)}
    domain = domain if domain is not None else make_domain(cfg.domain)
    generator = generator if generator is not None else make_generator(domain, cfg.algo.name)
    written = draw_archives(out, cfg, archives, domain.name)
    if (run_dir / METRICS_FILE).is_file():
        from nca_qd import viz

        viz.metric_curves(out / "curves.png", run_dir / METRICS_FILE)
        written.append(out / "curves.png")
    written += draw_best_layouts(out, cfg, archives["result"], domain, generator)
    return written


def draw_archives(
    out: Path, cfg: DictConfig, archives: Mapping[str, Mapping[str, Any]], domain_name: str
) -> list[Path]:
    """``archive_<which>.png``: each archive's objective over its measure grid."""
    from nca_qd import viz

    spec = archive_spec(cfg.algo, cfg.domain, cfg.qd)
    names = list(cfg.domain.measures.names)
    written = []
    for which, archive in archives.items():
        path = out / f"archive_{which}.png"
        viz.archive_heatmap(
            path,
            np.asarray(archive["objective"]),
            spec.cells,
            spec.ranges,
            names,
            title=f"{which} archive ({cfg.algo.name}, {domain_name})",
        )
        written.append(path)
    return written


def draw_best_layouts(
    out: Path, cfg: DictConfig, archive: Mapping[str, Any], domain: Domain, generator: Any
) -> list[Path]:
    """``best_<size>.png`` (and ``best_<size>_repaired.png``): the ``output.n_best`` best
    elites generated at the training and the evaluation size (directly searched layouts, which
    do not scale: the training size only)."""
    from nca_qd import viz

    cells = select_elites(np.asarray(archive["objective"]), int(cfg.output.n_best))
    if len(cells) == 0:
        return []
    genotypes = np.asarray(archive["genotypes"][cells])
    written = []
    sizes = ("train", "eval") if getattr(generator, "scalable", True) else ("train",)
    for which in sizes:
        layouts = [domain.assemble(r) for r in generate(domain, generator, genotypes, which)]
        h, w = layouts[0].shape
        path = out / f"best_{which}.png"
        viz.render_layouts(
            path, layouts, domain.layout_tiles, domain.palette, [f"cell {c} ({h}x{w})" for c in cells]
        )
        written.append(path)
        if cfg.domain.get("repair") is not None and cfg.output.get("repaired", True):
            written.append(draw_repaired(out, cfg, which, layouts, cells, domain))
    return written


def draw_repaired(
    out: Path, cfg: DictConfig, which: str, layouts: Sequence[np.ndarray], cells, domain: Domain
) -> Path:
    """``best_<which>_repaired.png``: each elite's layout repaired on the evaluation backend."""
    from nca_qd import viz
    from nca_qd.scoring.backend import make_backend, map_jobs
    from nca_qd.scoring.jobs import repair_job, repair_options

    opts = repair_options(cfg.domain, which)
    backend = make_backend(cfg.get("eval"))
    try:
        repaired = map_jobs(backend, repair_job, [(domain.name, lay, opts) for lay in layouts])
    finally:
        backend.close()
    shown, titles = [], []
    for lay, res, c in zip(layouts, repaired, cells):
        ok = getattr(res, "layout", None) is not None
        shown.append(res.layout if ok else lay)
        titles.append(f"cell {c} repaired, Hamming {res.hamming}" if ok else f"cell {c}: repair failed")
    path = out / f"best_{which}_repaired.png"
    viz.render_layouts(path, shown, domain.layout_tiles, domain.palette, titles)
    return path
