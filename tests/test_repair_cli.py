"""experiments.repair / experiments.render: outputs, and one-line errors (exit 2) on bad input."""

import json
import sys

import numpy as np
import pytest

from experiments import render as render_cli
from experiments import repair as repair_cli
from experiments.cli import main_guard
from nca_qd.io import load_map
from nca_qd.layouts import warehouse as wh
from nca_qd.repair import make_rules
from nca_qd.repair.validator import check

GOOD = [
    ".........",
    "w..e@e..w",
    "...e@e...",
    ".........",
    "w..e@@e.w",
    "....@e...",
    ".........",
]


def run(module, argv, monkeypatch):
    monkeypatch.setattr(sys, "argv", ["prog", *argv])
    with pytest.raises(SystemExit) as exc:
        main_guard(module.main)()
    return exc.value.code


def write(tmp_path, rows, name="in.json", **extra):
    path = tmp_path / name
    data = {"name": "t", "layout": rows, "n_row": len(rows), "n_col": len(rows[0]), **extra}
    path.write_text(json.dumps(data))
    return path


def test_repair_writes_a_valid_layout_and_one_json_line(tmp_path, monkeypatch, capsys):
    src = write(tmp_path, GOOD)
    out, png = tmp_path / "out.json", tmp_path / "cmp.png"
    code = run(
        repair_cli,
        ["domain=warehouse_even", f"layout={src}", f"out={out}", "n_shelves=6", f"render={png}"],
        monkeypatch,
    )
    assert code == 0
    line = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert line["valid"] is True and line["status"] in ("optimal", "feasible")
    assert {"hamming", "similarity", "seconds"} <= set(line)
    # the printed bound is proven: at most the distance found, and the gap says how far
    assert line["bound"] <= line["objective"] and 0.0 <= line["gap"] <= 1.0
    if line["status"] == "optimal":
        assert line["gap"] == 0.0
    assert "lower_bound" not in line
    lay = load_map(out, wh.TILES).to_array(wh.TILES)
    assert check(lay, make_rules("warehouse_even", lay.shape, n_shelves=6)) is None
    assert line["hamming"] == int((lay != load_map(src).to_array(wh.TILES)).sum())
    assert png.stat().st_size > 1000


@pytest.mark.parametrize(
    "rows, extra, expect",
    [
        (GOOD[:3] + ["...X....."] + GOOD[4:], {}, "unknown tile 'X' at row 3, column 3"),
        (GOOD[:3] + ["........"] + GOOD[4:], {}, "ragged rows"),
        (GOOD, {"n_row": 8}, "declares n_row=8"),
        (GOOD[:1] + [".e.e@e..w"] + GOOD[2:], {}, "workstation column not as the warehouse requires"),
        (["w" + r[1:] for r in GOOD], {}, "workstation column"),
    ],
)
def test_bad_input_one_line_exit_2(tmp_path, monkeypatch, capsys, rows, extra, expect):
    src = write(tmp_path, rows, **extra)
    code = run(
        repair_cli,
        ["domain=warehouse_even", f"layout={src}", f"out={tmp_path / 'o.json'}", "n_shelves=6"],
        monkeypatch,
    )
    err = capsys.readouterr().err.strip()
    assert code == 2
    assert len(err.splitlines()) == 1 and "Traceback" not in err
    assert str(src) in err and expect in err
    assert not (tmp_path / "o.json").exists()


def test_unknown_size_without_shelf_count_is_a_usage_error(tmp_path, monkeypatch, capsys):
    src = write(tmp_path, GOOD)
    code = run(
        repair_cli, ["domain=warehouse_even", f"layout={src}", f"out={tmp_path / 'o.json'}"], monkeypatch
    )
    err = capsys.readouterr().err
    assert code == 2 and "n_shelves" in err and str(src) in err


def test_manufacturing_repair_and_render(tmp_path, monkeypatch, capsys):
    rng = np.random.default_rng(0)
    rows = ["".join(".e012"[v] for v in row) for row in rng.integers(0, 5, size=(8, 9))]
    src = write(tmp_path, rows)
    out = tmp_path / "out.json"
    assert (
        run(repair_cli, ["domain=manufacturing", f"layout={src}", f"out={out}", "n_agents=10"], monkeypatch)
        == 0
    )
    assert json.loads(capsys.readouterr().out.strip().splitlines()[-1])["valid"] is True
    png = tmp_path / "pair.png"
    assert run(render_cli, [f"layout={src}", f"out={png}", f"compare={out}"], monkeypatch) == 0
    assert png.read_bytes()[:4] == b"\x89PNG"


def test_render_names_a_bad_file(tmp_path, monkeypatch, capsys):
    src = write(tmp_path, ["..Q", "..."])
    code = run(render_cli, [f"layout={src}", f"out={tmp_path / 'x.png'}"], monkeypatch)
    err = capsys.readouterr().err
    assert code == 2 and str(src) in err and "'Q'" in err


@pytest.mark.parametrize(
    "out, render, expect",
    [
        ("missing/o.json", None, "folder"),
        ("", None, "is a folder, not a file"),
        ("o.json", "missing/cmp.png", "render="),
    ],
)
def test_an_unwritable_output_is_refused_before_the_repair(
    tmp_path, monkeypatch, capsys, out, render, expect
):
    """Checked before the work, so that a repair is never computed and then lost."""
    import nca_qd.repair as repair_module

    src = write(tmp_path, GOOD)
    calls = []
    monkeypatch.setattr(
        repair_cli, "repair", lambda *a, **k: calls.append(1) or repair_module.repair(*a, **k)
    )
    argv = ["domain=warehouse_even", f"layout={src}", f"out={tmp_path / out}", "n_shelves=6"]
    if render:
        argv.append(f"render={tmp_path / render}")
    code = run(repair_cli, argv, monkeypatch)
    err = capsys.readouterr().err.strip()
    assert code == 2 and len(err.splitlines()) == 1 and expect in err
    assert not calls


def test_tile_repairs_the_layout_repeated_to_a_larger_map(tmp_path, monkeypatch, capsys):
    """tile=[R,C]: the paper's tiling baseline (its appendix E) from one command: the storage
    region (between the two-column workstation frames) repeated from the top left and cropped,
    the frame added, then repaired at that size."""
    src = write(tmp_path, GOOD)
    out = tmp_path / "tiled.json"
    region = np.array([list(r[2:-2]) for r in GOOD])  # 7 x 5
    want = np.tile(region, (2, 3))[:14, :12]  # the storage region of a 14 x 16 map
    n_shelves = int((want == "@").sum())
    code = run(
        repair_cli,
        ["domain=warehouse_even", f"layout={src}", f"out={out}", "tile=[14,16]", f"n_shelves={n_shelves}"],
        monkeypatch,
    )
    assert code == 0
    line = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    lay = load_map(out, wh.TILES).to_array(wh.TILES)
    assert lay.shape == (14, 16) and line["valid"] is True
    assert check(lay, make_rules("warehouse_even", lay.shape, n_shelves=n_shelves)) is None
    got = np.array([list(r) for r in load_map(out).rows])[:, 2:-2]
    assert line["hamming"] == int((got != want).sum())  # the frame is not the repair's to change
    saved = json.loads(out.read_text())  # named as a tiling, from what
    assert saved["name"].endswith("_tiled_14x16_repaired") and saved["tiled_from"].endswith("(7x9)")
    code = run(repair_cli, ["domain=warehouse_even", f"layout={src}", f"out={out}", "tile=[14]"], monkeypatch)
    err = capsys.readouterr().err.strip()
    assert code == 2 and len(err.splitlines()) == 1 and "tile must be [rows, cols]" in err


def test_render_crops_a_wide_layout_to_its_corner(tmp_path, monkeypatch, capsys):
    import nca_qd.viz as viz

    src = write(tmp_path, GOOD)
    drawn = []
    real = viz.render_layouts

    def spy(out, layouts, tiles, palette, titles):
        drawn.append(([a.copy() for a in layouts], list(titles)))
        return real(out, layouts, tiles, palette, titles)

    monkeypatch.setattr(viz, "render_layouts", spy)
    corner = tmp_path / "corner.png"
    assert run(render_cli, [f"layout={src}", f"out={corner}", "crop=[3,4]"], monkeypatch) == 0
    (lay,), (title,) = drawn[0]
    want = np.array([[wh.TILES.index(ch) for ch in row[:4]] for row in GOOD[:3]])
    np.testing.assert_array_equal(lay, want)
    assert "top-left 3x4 of 7x9" in title and corner.read_bytes()[:4] == b"\x89PNG"
    capsys.readouterr()
    assert run(render_cli, [f"layout={src}", f"out={corner}", "crop=[3]"], monkeypatch) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "crop must be [rows, cols]" in err


def test_keep_aisles_holds_the_shelf_free_rows_and_the_file_says_so(tmp_path, monkeypatch, capsys):
    src = write(tmp_path, GOOD)
    out = tmp_path / "out.json"
    argv = ["domain=warehouse_even", f"layout={src}", f"out={out}", "n_shelves=6", "keep_aisles=true"]
    assert run(repair_cli, argv, monkeypatch) == 0
    assert json.loads(capsys.readouterr().out.strip().splitlines()[-1])["valid"] is True
    lay = load_map(out, wh.TILES).to_array(wh.TILES)
    before = load_map(src).to_array(wh.TILES)
    held = wh.aisle_rows(before)
    assert held.any() and np.array_equal(lay[held], before[held])
    written = json.loads(out.read_text())
    assert written["repair"]["keep_aisles"] is True and written["name"] == "t_repaired_aisles_kept"
    src = write(tmp_path, ["." * 7] * 6, name="m.json")
    argv = ["domain=manufacturing", f"layout={src}", f"out={out}", "n_agents=12", "keep_aisles=true"]
    assert run(repair_cli, argv, monkeypatch) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "manufacturing layouts have no aisles to keep" in err[0]
