"""benchmarks.tiling_layouts: shelves added and removed against the plain tiling, dead ends and
their bands, counted on hand-built layouts; a size mismatch or a missing file is one line, exit 2."""

import json

import numpy as np

from benchmarks import tiling_layouts
from nca_qd.evaluation.layouts import tile_layout
from nca_qd.io import array_to_rows, load_map, reference_maps_dir
from nca_qd.repair import tiles_of

SMALL = reference_maps_dir() / "warehouse" / "paper_cma-mae_a5_even_33x36.json"
TILES = tiles_of("warehouse_even")


def write(path, rows):
    path.write_text(
        json.dumps({"name": path.stem, "n_row": len(rows), "n_col": len(rows[0]), "layout": rows})
    )
    return str(path)


def test_counts_against_the_plain_tiling(tmp_path, capsys):
    plain = tile_layout("warehouse_even", load_map(SMALL, TILES).to_array(TILES), [66, 72])
    rows = [list(r) for r in array_to_rows(plain, TILES)]
    # two open tiles from row 50 on become shelves, one shelf near the top is removed
    changed = []
    for r in range(50, 66):
        for c in range(4, 68):
            if (
                rows[r][c] == "."
                and len(changed) < 2
                and all(abs(r - a) + abs(c - b) > 4 for a, b in changed)
            ):
                changed.append((r, c))
    for r, c in changed:
        rows[r][c] = "@"
    top = next((r, c) for r in range(66) for c in range(72) if rows[r][c] == "@")
    rows[top[0]][top[1]] = "."
    path = write(tmp_path / "edited.json", ["".join(r) for r in rows])
    assert tiling_layouts.main([str(SMALL), path, "--band", "20"]) == 0
    out = [json.loads(line) for line in capsys.readouterr().out.strip().splitlines()]
    assert out[0]["shelves"] == int((plain == TILES.index("@")).sum())
    got = out[1]
    assert got["shelves_added"] == 2 and got["shelves_removed"] == 1 and got["hamming_to_tiling"] == 3
    assert got["added_by_band"] == [sum(b <= r < b + 20 for r, _ in changed) for b in (0, 20, 40, 60)]
    ends = tiling_layouts.dead_ends(np.array([[c != "@" for c in r] for r in rows]))
    assert got["dead_ends"] == int(ends.sum()) and sum(got["dead_ends_by_band"]) == got["dead_ends"]
    # recount the dead ends by hand: a traversable tile with at most one traversable neighbour
    hand = 0
    for r in range(66):
        for c in range(72):
            if rows[r][c] == "@":
                continue
            nb = sum(
                0 <= r + dr < 66 and 0 <= c + dc < 72 and rows[r + dr][c + dc] != "@"
                for dr, dc in ((0, 1), (1, 0), (0, -1), (-1, 0))
            )
            hand += nb <= 1
    assert hand == got["dead_ends"]


def test_dead_ends_are_open_tiles_with_at_most_one_open_neighbour():
    free = np.array([[1, 1, 0, 1], [0, 1, 0, 0], [0, 1, 1, 0]], dtype=bool)
    # (0, 0) and (2, 2) end a corridor; (0, 3) is cut off from all sides; shelves never count
    expect = np.zeros_like(free)
    expect[0, 0] = expect[2, 2] = expect[0, 3] = True
    np.testing.assert_array_equal(tiling_layouts.dead_ends(free), expect)
    assert tiling_layouts.by_band(expect, 2) == [2, 1]


def test_a_size_mismatch_or_missing_file_is_one_line_exit_2(tmp_path, capsys):
    small, big = str(SMALL), str(reference_maps_dir() / "warehouse" / "human_101x102.json")
    for args, message in (
        ([small, big, small], "the tiling is"),
        ([small, str(tmp_path / "none.json")], "none.json"),
    ):
        assert tiling_layouts.main(args) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and err[0].startswith("error:") and message in err[0]
