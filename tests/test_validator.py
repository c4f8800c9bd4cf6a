"""The independent validator: names each violated constraint and where; human layouts pass."""

import pytest

from nca_qd.io import load_map, reference_maps_dir, rows_to_array
from nca_qd.layouts import manufacturing as mf
from nca_qd.layouts import warehouse as wh
from nca_qd.repair import make_rules
from nca_qd.repair.validator import check, violation_mask, violations

MAPS = reference_maps_dir()

# A valid 7x9 warehouse (storage 7x5), 4 shelves.
WAREHOUSE = [
    ".........",
    "w..e@e..w",
    ".........",
    ".........",
    "w..e@@e.w",
    "....e....",
    ".........",
]


def wh_layout(rows):
    return rows_to_array(rows, wh.TILES)


def test_small_warehouse_is_valid():
    assert check(wh_layout(WAREHOUSE), wh.rules((7, 9), n_shelves=3)) is None


@pytest.mark.parametrize(
    "edit, constraint, cell",
    [
        ((2, 5, "e"), "adjacency", (2, 5)),  # endpoint without a shelf
        ((0, 4, "@"), "adjacency", (0, 4)),  # shelf without an endpoint
        ((1, 0, "."), "fixed", (1, 0)),  # workstation removed
        ((1, 1, "@"), "fixed", (1, 1)),  # the empty column next to it
    ],
)
def test_single_edits_are_named(edit, constraint, cell):
    rows = [list(r) for r in WAREHOUSE]
    r, c, ch = edit
    rows[r][c] = ch
    lay = wh_layout(["".join(x) for x in rows])
    found = violations(lay, wh.rules((7, 9), n_shelves=3))
    assert found, "the edit must be reported"
    assert found[0].constraint == constraint and found[0].cell == cell


def test_shelf_without_endpoint_and_enclosed_pocket():
    rows = [
        ".........",
        "w.@@@@@.w",
        "..@...@..",
        "..@@@@@..",
        "w...e...w",
        ".........",
        ".........",
    ]
    found = violations(wh_layout(rows), wh.rules((7, 9), n_shelves=12))
    kinds = {v.constraint for v in found}
    assert {"connectivity", "adjacency"} <= kinds
    pocket = [v for v in found if v.constraint == "connectivity"][0]
    assert pocket.cell in {(2, 3), (2, 4), (2, 5)}
    assert "cannot reach" in pocket.message
    mask = violation_mask(wh_layout(rows), wh.rules((7, 9), n_shelves=12))
    assert mask[2, 3:6].all() and mask[1, 2]


def test_shelf_count_is_checked():
    found = violations(wh_layout(WAREHOUSE), wh.rules((7, 9), n_shelves=5))
    assert [v.constraint for v in found] == ["count"]
    assert "shelves: 3" in found[0].message


def test_manufacturing_rules():
    rows = ["......", ".e0e..", "..e...", "......"]
    lay = rows_to_array(rows, mf.TILES)
    found = violations(lay, mf.rules(lay.shape, n_agents=5))
    names = [v.message for v in found]
    assert any("kind 1" in m for m in names) and any("kind 2" in m for m in names)
    rows = ["......", ".e0e..", "..1e..", "..e2e."]
    lay = rows_to_array(rows, mf.TILES)
    assert check(lay, mf.rules(lay.shape, n_agents=5)) is None
    assert check(lay, mf.rules(lay.shape, n_agents=100)).constraint == "count"


@pytest.mark.skipif(not MAPS.is_dir(), reason="shared reference maps not present")
@pytest.mark.parametrize(
    "domain, folder", [("warehouse_even", "warehouse"), ("manufacturing", "manufacturing")]
)
def test_human_layouts_validate(domain, folder):
    files = sorted((MAPS / folder).glob("human_*.json"))
    assert len(files) == 7
    tiles = wh.TILES if folder == "warehouse" else mf.TILES
    for f in files:
        lay = load_map(f, tiles).to_array(tiles)
        assert check(lay, make_rules(domain, lay.shape)) is None, f.name
        if folder == "warehouse":
            assert int((lay == wh.SHELF).sum()) == wh.default_shelves(lay.shape)


@pytest.mark.skipif(not MAPS.is_dir(), reason="shared reference maps not present")
def test_paper_layouts():
    rep = load_map(MAPS / "warehouse/paper_cma-mae_a5_even_33x36.json").to_array(wh.TILES)
    unrep = load_map(MAPS / "warehouse/paper_cma-mae_a5_even_33x36_unrepaired.json").to_array(wh.TILES)
    rules = make_rules("warehouse_even", rep.shape)
    assert check(rep, rules) is None
    assert check(unrep, rules) is not None
