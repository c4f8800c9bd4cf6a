"""Layouts on disk: the paper's JSON map format, and atomic writes.

A map file is ``{"name", "layout": [row strings], "n_row", "n_col", ...}`` with rows read top to
bottom. In memory a layout is an ``int`` array ``[n_row, n_col]`` of indices into a tile alphabet
string (``tiles[layout[i, j]]`` is the character). Loading checks the declared sizes against the
rows (the public 101x102 warehouse file declared n_col=98 for 102-wide rows) and every character
against the alphabet, and names the file and the defect when something is wrong.
"""

from __future__ import annotations

import json
import os
import tempfile
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from nca_qd.errors import MapFormatError


@dataclass
class MapFile:
    """A layout read from (or to be written to) a JSON map file."""

    name: str
    rows: list[str]
    extra: dict[str, Any] = field(default_factory=dict)

    @property
    def shape(self) -> tuple[int, int]:
        return len(self.rows), len(self.rows[0]) if self.rows else 0

    def to_array(self, tiles: str) -> np.ndarray:
        """Rows as an int array of indices into ``tiles``."""
        return rows_to_array(self.rows, tiles, source=self.name)


def rows_to_array(rows: list[str], tiles: str, source: str = "layout") -> np.ndarray:
    """Convert row strings to an ``int32`` array of tile indices; unknown characters are an error."""
    lookup = {ch: i for i, ch in enumerate(tiles)}
    out = np.empty((len(rows), len(rows[0]) if rows else 0), dtype=np.int32)
    for r, row in enumerate(rows):
        for c, ch in enumerate(row):
            if ch not in lookup:
                raise MapFormatError(
                    f"{source}: unknown tile {ch!r} at row {r}, column {c} (expected one of {tiles!r})"
                )
            out[r, c] = lookup[ch]
    return out


def array_to_rows(layout: np.ndarray, tiles: str) -> list[str]:
    """Inverse of :func:`rows_to_array`."""
    layout = np.asarray(layout)
    if layout.ndim != 2:
        raise ValueError(f"layout must be 2-D, got shape {layout.shape}")
    return ["".join(tiles[int(v)] for v in row) for row in layout]


def load_map(path: str | os.PathLike, tiles: str | None = None) -> MapFile:
    """Read a JSON map file, checking its structure (and its characters if ``tiles`` is given)."""
    path = Path(path)
    if not path.is_file():
        raise MapFormatError(f"{path}: no such map file")
    try:
        data = json.loads(path.read_text())
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise MapFormatError(f"{path}: not valid JSON ({exc})") from None
    if not isinstance(data, dict) or not isinstance(data.get("layout"), list):
        raise MapFormatError(f"{path}: expected an object with a 'layout' list of row strings")
    rows = data["layout"]
    if not rows or not all(isinstance(r, str) for r in rows):
        raise MapFormatError(f"{path}: 'layout' must be a non-empty list of strings")
    widths = {len(r) for r in rows}
    if len(widths) != 1:
        bad = next(i for i, r in enumerate(rows) if len(r) != len(rows[0]))
        raise MapFormatError(
            f"{path}: ragged rows (row 0 has {len(rows[0])} tiles, row {bad} has {len(rows[bad])})"
        )
    n_row, n_col = len(rows), len(rows[0])
    for key, actual in (("n_row", n_row), ("n_col", n_col)):
        declared = data.get(key)
        if declared is not None and declared != actual:
            raise MapFormatError(f"{path}: declares {key}={declared} but the layout has {actual}")
    extra = {k: v for k, v in data.items() if k not in ("name", "layout", "n_row", "n_col")}
    mf = MapFile(name=str(data.get("name", path.stem)), rows=list(rows), extra=extra)
    if tiles is not None:
        rows_to_array(mf.rows, tiles, source=str(path))
    return mf


def save_map(path: str | os.PathLike, mapfile: MapFile) -> None:
    """Write a map file atomically, in the paper's format (name, layout, n_row, n_col, extras)."""
    n_row, n_col = mapfile.shape
    data = {"name": mapfile.name, **mapfile.extra, "n_row": n_row, "n_col": n_col, "layout": mapfile.rows}
    atomic_write_text(path, json.dumps(data, indent=4))


def atomic_write_bytes(path: str | os.PathLike, payload: bytes) -> None:
    """Write ``payload`` to ``path`` so that readers see the old file or the new one, never half.
    The file gets the mode a plain ``open`` would give it (0666 less the umask), not the
    private 0600 of a temporary file: collaborators on a shared machine can read a run."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    try:
        fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    except OSError as exc:  # a folder that takes no files: name the file asked for, not the temporary
        raise type(exc)(exc.errno, exc.strerror, str(path)) from None
    try:
        os.fchmod(fd, 0o666 & ~_umask())
        with os.fdopen(fd, "wb") as fh:
            fh.write(payload)
            fh.flush()
            os.fsync(fh.fileno())
        os.replace(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise


def _umask() -> int:
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


def atomic_write_text(path: str | os.PathLike, text: str) -> None:
    atomic_write_bytes(path, text.encode())


def save_pytree(path: str | os.PathLike, tree: Any, compress: bool = False) -> None:
    """Serialise a pytree of arrays (a QD state) atomically with Flax's msgpack format;
    ``compress``: zlib over it (a maze agent's level buffer of 0/1 tiles shrinks ~20x)."""
    import zlib

    from flax import serialization

    data = serialization.to_bytes(tree)
    atomic_write_bytes(path, zlib.compress(data, 6) if compress else data)


def load_pytree(path: str | os.PathLike, template: Any) -> Any:
    """Restore a pytree saved by :func:`save_pytree` (compressed or not) into the structure of
    ``template``."""
    import zlib

    from flax import serialization

    from nca_qd.errors import NcaQdError

    data = Path(path).read_bytes()
    try:
        if data[:1] == b"\x78":  # a zlib stream (a msgpack state starts with a map: 0x8_ / 0xde / 0xdf)
            data = zlib.decompress(data)
        return serialization.from_bytes(template, data)
    except (ValueError, KeyError, TypeError, zlib.error) as exc:
        raise NcaQdError(f"{path}: checkpoint does not match this configuration ({exc})") from None


def save_npz(path: str | os.PathLike, arrays: dict[str, np.ndarray]) -> None:
    """Write arrays as one ``.npz`` file atomically."""
    import io as _io

    buf = _io.BytesIO()
    np.savez_compressed(buf, **arrays)
    atomic_write_bytes(path, buf.getvalue())


def reference_maps_dir() -> Path:
    """Where the paper's reference layouts live: ``$NCA_QD_MAPS``, else ``shared/reference/maps``
    beside the repository (the project's checkout layout), else ``/work/shared/reference/maps``.
    The directory may not exist; callers skip or explain."""
    env = os.environ.get("NCA_QD_MAPS")
    if env:
        return Path(env)
    beside = Path(__file__).resolve().parents[2] / "shared" / "reference" / "maps"
    return beside if beside.is_dir() else Path("/work/shared/reference/maps")
