"""Render layout files to PNG in the paper's colours.

    python -m experiments.render layout=a.json out=a.png [compare=b.json] [domain=...]

The core call is :func:`render_files` (a list of map files and titles -> one PNG), so archive
elites can be drawn the same way. Without ``domain`` the alphabet is inferred from the tiles.
"""

from __future__ import annotations

from pathlib import Path
from typing import Sequence

from experiments.cli import compose_config, main_guard
from nca_qd.errors import NcaQdError
from nca_qd.io import load_map
from nca_qd.repair import DOMAIN_NAMES
from nca_qd.repair import manufacturing as mf
from nca_qd.repair import warehouse as wh


def tiles_and_palette(domain: str | None, chars: set[str]) -> tuple[str, dict[str, str]]:
    """Alphabet and palette of ``domain``, or guessed from the characters used."""
    if domain is None:
        if chars & set("012"):
            domain = "manufacturing"
        elif chars <= set(wh.TILES):
            domain = "warehouse_even"
        else:
            domain = "manufacturing"
    if domain not in DOMAIN_NAMES:
        raise NcaQdError(f"unknown domain {domain!r} (known: {', '.join(DOMAIN_NAMES)})")
    if domain == "manufacturing":
        return mf.TILES, mf.PALETTE
    return wh.TILES, wh.PALETTE


def render_files(out: str | Path, paths: Sequence[str | Path], titles: Sequence[str] | None = None,
                 domain: str | None = None) -> None:
    """Draw the layouts of ``paths`` side by side into the PNG ``out``."""
    from nca_qd.viz import render_layouts

    maps = [load_map(p) for p in paths]
    chars = set("".join("".join(m.rows) for m in maps))
    tiles, palette = tiles_and_palette(domain, chars)
    # load_map with the alphabet names the file and the character when a tile does not fit.
    layouts = [load_map(p, tiles).to_array(tiles) for p in paths]
    titles = list(titles) if titles is not None else [m.name for m in maps]
    render_layouts(out, layouts, tiles, palette, titles)


def main(argv: list[str]) -> int:
    cfg = compose_config("render", argv)
    if not cfg.layout or not cfg.out:
        raise NcaQdError("give layout=<file.json> and out=<file.png>")
    paths = [cfg.layout] + ([cfg.compare] if cfg.compare else [])
    domain = cfg.domain.name if cfg.get("domain") is not None else None
    render_files(cfg.out, paths, domain=domain)
    print(cfg.out)
    return 0


if __name__ == "__main__":
    main_guard(main)()
