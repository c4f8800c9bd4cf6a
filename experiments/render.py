"""Render layout files or archive elites to PNG in the paper's colours.

    python -m experiments.render layout=a.json out=a.png [compare=b.json] [domain=...]
    python -m experiments.render run=<run dir> out=elites.png [elites=4 | elites=[12,340]] [size=eval]
    python -m experiments.render run=<run dir> pictures=true [out=<dir>]

``pictures=true`` draws every picture a finished run has (archives, curves, best elites at both
sizes, repaired) from what the run directory holds — also for a run in progress or a committed
snapshot on a fresh clone — into ``out`` (default: the run directory).

The core call is :func:`render_files` (a list of map files and titles -> one PNG); archive elites
are generated from the run's archive at the training or evaluation size and drawn the same way.
Without ``domain`` the alphabet is inferred from the tiles.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

from experiments.cli import check_writable, compose_config, main_guard, size_pair
from nca_qd.domains import domain_class
from nca_qd.errors import NcaQdError, require_bool
from nca_qd.io import load_map


def tiles_and_palette(domain: str | None, chars: set[str]) -> tuple[str, dict[str, str]]:
    """Alphabet and palette of ``domain``, or of the first registered domain whose alphabet
    holds most of the characters used (all of them, for a well-formed map; otherwise the map
    reader then names the character that does not fit)."""
    from nca_qd.domains import DOMAINS

    if domain is None:
        domain = max(DOMAINS, key=lambda name: len(chars & set(domain_class(name).layout_tiles)))
    cls = domain_class(domain)
    return cls.layout_tiles, dict(cls.palette)


def render_files(
    out: str | Path,
    paths: Sequence[str | Path],
    titles: Sequence[str] | None = None,
    domain: str | None = None,
    crop: Sequence[int] | None = None,
) -> None:
    """Draw the layouts of ``paths`` side by side into the PNG ``out``; ``crop`` [rows, cols]:
    only their top-left corner of that size (a 140x500 map drawn whole is too thin to read)."""
    from nca_qd.viz import render_layouts

    maps = [load_map(p) for p in paths]
    chars = set("".join("".join(m.rows) for m in maps))
    tiles, palette = tiles_and_palette(domain, chars)
    # load_map with the alphabet names the file and the character when a tile does not fit.
    layouts = [load_map(p, tiles).to_array(tiles) for p in paths]
    titles = list(titles) if titles is not None else [m.name for m in maps]
    if crop is not None:
        r, c = size_pair(crop, "crop")
        titles = [
            f"{t} (top-left {min(r, a.shape[0])}x{min(c, a.shape[1])} of {a.shape[0]}x{a.shape[1]})"
            for t, a in zip(titles, layouts)
        ]
        layouts = [a[:r, :c] for a in layouts]
    render_layouts(out, layouts, tiles, palette, titles)


def render_elites(out: str | Path, run_dir: str | Path, elites, size: str = "train") -> None:
    """Generate chosen elites of a run's result archive and draw them side by side."""
    import numpy as np
    from omegaconf import OmegaConf

    from nca_qd.domains import make_domain
    from nca_qd.pipeline import generate, make_generator
    from nca_qd.run_dir import load_archive, load_run_config, select_elites
    from nca_qd.viz import render_layouts

    if size not in ("train", "eval"):
        raise NcaQdError(f"size must be train or eval, got {size!r}")
    cfg = load_run_config(Path(run_dir))
    archive = load_archive(run_dir, "result")
    if isinstance(elites, int) or (isinstance(elites, str) and elites.isdigit()):
        cells = select_elites(archive["objective"], int(elites))
    else:
        cells = np.asarray(OmegaConf.to_object(elites) if not isinstance(elites, list) else elites, dtype=int)
        bad = [
            int(c)
            for c in cells
            if not (0 <= c < archive["objective"].size) or not np.isfinite(archive["objective"][c])
        ]
        if bad:
            raise NcaQdError(f"{run_dir}: no elite in cell(s) {bad}")
    if len(cells) == 0:
        raise NcaQdError(f"{run_dir}: the archive is empty")
    domain = make_domain(cfg.domain)
    regions = generate(domain, make_generator(domain, cfg.algo.name), archive["genotypes"][cells], size)
    layouts = [domain.assemble(r) for r in regions]
    titles = [f"cell {c}: f={archive['objective'][c]:.3g}" for c in cells]
    render_layouts(out, layouts, domain.layout_tiles, domain.palette, titles)


def main(argv: list[str]) -> int:
    cfg = compose_config("render", argv)
    require_bool("pictures", cfg.pictures)
    if cfg.get("run") and cfg.pictures:
        from nca_qd.run_dir import load_run_config
        from nca_qd.run_pictures import write_run_pictures

        for path in write_run_pictures(cfg.run, load_run_config(cfg.run), out_dir=cfg.out or cfg.run):
            print(path)
        return 0
    if cfg.get("run") and cfg.out:
        check_writable(cfg.out, "out")
        render_elites(cfg.out, cfg.run, cfg.elites, cfg.size)
        print(cfg.out)
        return 0
    if not cfg.layout or not cfg.out:
        raise NcaQdError(
            "give layout=<file.json> out=<file.png>, run=<run dir> out=<file.png>, "
            "or run=<run dir> pictures=true"
        )
    check_writable(cfg.out, "out")
    paths = [cfg.layout] + ([cfg.compare] if cfg.compare else [])
    domain = cfg.domain.name if cfg.get("domain") is not None else None
    render_files(cfg.out, paths, domain=domain, crop=cfg.get("crop"))
    print(cfg.out)
    return 0


if __name__ == "__main__":
    main_guard(main)()
