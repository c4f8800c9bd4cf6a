"""Warehouse and manufacturing domains: seeds, frame, measures, registry."""

import numpy as np
import pytest

from experiments.cli import compose_config
from nca_qd.domains import make_domain
from nca_qd.io import load_map, reference_maps_dir
from nca_qd.layouts import warehouse as wh

MAPS = reference_maps_dir()


def domain(name):
    cfg = compose_config("repair", [f"domain={name}"]).domain
    return make_domain(cfg)


@pytest.mark.parametrize("name", ["warehouse_even", "warehouse_uneven", "manufacturing"])
def test_registry_and_config(name):
    d = domain(name)
    assert d.name == name and d.layout_tiles.startswith(d.gen_tiles)
    assert set(d.palette) == set(d.layout_tiles)
    full = d.assemble(d.seed(d.gen_shape("eval")))
    assert full.shape == ((101, 102))


def test_warehouse_frame_matches_human_layout_rule():
    lay = wh.assemble(np.zeros((33, 32), dtype=np.int32))
    ws = np.argwhere(lay == wh.WORKSTATION)
    assert len(ws) == 22 and set(ws[:, 1]) == {0, 35}
    assert all((r - 1) % 3 == 0 and 0 < r < 32 for r in ws[:, 0])
    assert (lay[:, [1, 34]] == wh.EMPTY).all()


@pytest.mark.skipif(not MAPS.is_dir(), reason="shared reference maps not present")
def test_seeds_and_frame_reproduce_shared_maps():
    d, m = domain("warehouse_even"), domain("manufacturing")
    for shape in ((33, 32), (101, 98)):
        ref = load_map(MAPS / f"warehouse/seed_storage_{shape[0]}x{shape[1]}.json").to_array(d.gen_tiles)
        assert np.array_equal(d.seed(shape), ref)
    for shape in ((33, 36), (101, 102)):
        ref = load_map(MAPS / f"manufacturing/seed_{shape[0]}x{shape[1]}.json").to_array(m.gen_tiles)
        assert np.array_equal(m.seed(shape), ref)
    human = load_map(MAPS / "warehouse/human_101x102.json").to_array(d.layout_tiles)
    assert np.array_equal(d.assemble(wh.storage(human)), human)


def test_seed_is_centred_at_other_sizes():
    s = domain("manufacturing").seed((45, 47))
    rows, cols = np.nonzero(s)
    assert (rows.min(), rows.max()) == (21, 23) and (cols.min(), cols.max()) == (21, 24)


def test_measures():
    d = domain("warehouse_even")
    storage = np.zeros((5, 6), dtype=np.int32)
    storage[1, 1] = storage[1, 2] = storage[3, 4] = wh.SHELF
    meas = d.measures(d.assemble(storage)[None])
    assert meas.shape == (1, 2) and meas[0, 1] == 2.0 and 0 < meas[0, 0] < 1
    m = domain("manufacturing")
    lay = np.zeros((4, 4), dtype=np.int32)
    lay[0, 0], lay[1, 1], lay[2, 2] = 2, 3, 1
    assert m.measures(lay[None])[0, 1] == 2.0
    assert m.measures(np.zeros((1, 4, 4), dtype=np.int32))[0, 0] == 0.0
