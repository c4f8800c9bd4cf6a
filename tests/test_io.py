"""Map files: the shared layouts load, defects are named with the file."""

import json

import numpy as np
import pytest

from nca_qd.errors import MapFormatError
from nca_qd.io import MapFile, array_to_rows, load_map, save_map


def _write(tmp_path, data, name="m.json"):
    path = tmp_path / name
    path.write_text(json.dumps(data))
    return path


def test_every_shared_map_loads_with_its_alphabet(maps_dir):
    alphabets = {"warehouse": ".@ew", "manufacturing": ".e012", "maze": " X"}
    files = sorted(maps_dir.glob("*/*.json"))
    assert len(files) >= 20
    for path in files:
        mf = load_map(path, alphabets[path.parent.name])
        assert mf.shape == (len(mf.rows), len(mf.rows[0]))


def test_declared_size_disagreeing_with_rows_is_an_error(tmp_path):
    path = _write(tmp_path, {"name": "x", "n_row": 2, "n_col": 98, "layout": ["..", ".."]})
    with pytest.raises(MapFormatError, match=r"m\.json: declares n_col=98 but the layout has 2"):
        load_map(path)


def test_ragged_rows_and_unknown_tiles_are_errors(tmp_path):
    with pytest.raises(MapFormatError, match="ragged rows"):
        load_map(_write(tmp_path, {"layout": ["...", ".."]}))
    with pytest.raises(MapFormatError, match=r"unknown tile 'Q' at row 1, column 0"):
        load_map(_write(tmp_path, {"layout": ["..", "Q."]}), tiles=".@")
    with pytest.raises(MapFormatError, match="not valid JSON"):
        (tmp_path / "bad.json").write_text("{nope")
        load_map(tmp_path / "bad.json")
    with pytest.raises(MapFormatError, match="no such map file"):
        load_map(tmp_path / "missing.json")


def test_round_trip_through_save(tmp_path):
    layout = np.array([[0, 1, 2], [2, 1, 0]])
    rows = array_to_rows(layout, ".@e")
    save_map(tmp_path / "out.json", MapFile("t", rows, {"weight": False}))
    back = load_map(tmp_path / "out.json", ".@e")
    np.testing.assert_array_equal(back.to_array(".@e"), layout)
    data = json.loads((tmp_path / "out.json").read_text())
    assert data["n_row"] == 2 and data["n_col"] == 3 and data["weight"] is False


@pytest.mark.parametrize("compress", [False, True])
def test_pytree_round_trip_compressed_or_not_and_a_truncated_file_is_one_error(tmp_path, compress):
    from nca_qd.errors import NcaQdError
    from nca_qd.io import load_pytree, save_pytree

    tree = {"layouts": np.zeros((50, 66, 66), np.int32), "step": np.int64(7), "w": np.arange(5.0)}
    tree["layouts"][:, ::3] = 1
    path = tmp_path / "ckpt.msgpack"
    save_pytree(path, tree, compress=compress)
    size = path.stat().st_size
    assert (size < tree["layouts"].nbytes / 20) == compress
    back = load_pytree(path, {k: np.zeros_like(v) for k, v in tree.items()})
    assert all(np.array_equal(back[k], tree[k]) for k in tree)
    path.write_bytes(path.read_bytes()[: size // 2])
    with pytest.raises(NcaQdError, match="checkpoint does not match"):
        load_pytree(path, tree)


def test_atomic_writes_take_the_umask_not_a_private_mode(tmp_path):
    import os

    from nca_qd.io import atomic_write_text

    old = os.umask(0o022)
    try:
        atomic_write_text(tmp_path / "a.txt", "x")
        os.umask(0o077)
        atomic_write_text(tmp_path / "b.txt", "y")
    finally:
        os.umask(old)
    assert (tmp_path / "a.txt").stat().st_mode & 0o777 == 0o644
    assert (tmp_path / "b.txt").stat().st_mode & 0o777 == 0o600
    assert not list(tmp_path.glob(".*.tmp"))


def test_the_package_says_its_version():
    import tomllib
    from pathlib import Path

    import nca_qd

    meta = tomllib.loads((Path(__file__).resolve().parents[1] / "pyproject.toml").read_text())
    assert nca_qd.__version__ == meta["project"]["version"]


def test_a_folder_that_takes_no_files_is_reported_with_the_file_asked_for(tmp_path, monkeypatch):
    """The temporary file beside the target is an implementation detail: a failure to create it
    names the target (what the user wrote on the command line), with the system's reason."""
    import errno
    import tempfile

    from nca_qd.io import atomic_write_text

    def refuse(**kwargs):
        raise PermissionError(errno.EACCES, "Permission denied", f"{kwargs['dir']}/.x.tmp")

    monkeypatch.setattr(tempfile, "mkstemp", refuse)
    target = tmp_path / "out.json"
    with pytest.raises(PermissionError) as exc:
        atomic_write_text(target, "{}")
    assert exc.value.filename == str(target) and exc.value.strerror == "Permission denied"
    assert list(tmp_path.iterdir()) == []
