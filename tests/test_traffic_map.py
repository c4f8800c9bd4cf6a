"""benchmarks.traffic_map: the visits are every agent's every timestep, the shares partition
them, a recorded run is reused, and a bad file is one line, exit 2."""

import json

import numpy as np

from benchmarks import traffic_map
from nca_qd.io import reference_maps_dir

HUMAN = reference_maps_dir() / "warehouse" / "human_33x36.json"


def test_visits_count_every_agent_timestep_and_a_recorded_run_is_reused(tmp_path, monkeypatch, capsys):
    assert traffic_map.main([str(HUMAN), "--agents", "20", "--T", "60", "--out", str(tmp_path)]) == 0
    row = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    with np.load(tmp_path / "human_33x36_20_s0.npz") as z:
        visits = z["visits"]
    assert int(visits.sum()) == 20 * 60  # agent-timesteps 1..T, every agent somewhere
    lay = np.array([list(r) for r in traffic_map.load_map(HUMAN).rows])
    assert not visits[lay == "@"].any()  # nobody stands on a shelf
    assert abs(row["near_workstations"] + row["corridor_rows"] + row["other_storage"] - 1) < 1e-3
    packed = visits[visits > 0.9 * 60].sum() / visits.sum()
    assert abs(row["on_packed_tiles"] - packed) < 1e-3
    assert (tmp_path / "traffic_20.png").stat().st_size > 1000

    def no_simulation(*a, **k):
        raise AssertionError("simulated again")

    monkeypatch.setattr(traffic_map, "exact_run", no_simulation)
    assert traffic_map.main([str(HUMAN), "--agents", "20", "--T", "60", "--out", str(tmp_path)]) == 0
    assert json.loads(capsys.readouterr().out.strip().splitlines()[-1]) == row


def test_a_missing_layout_is_one_line_exit_2(tmp_path, capsys):
    assert traffic_map.main([str(tmp_path / "none.json"), "--agents", "5", "--out", str(tmp_path)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("error:") and "none.json" in err[0]


def test_jam_extent_bounds_the_rows_and_columns_a_jam_fills():
    # a 10 x 14 map (2 frame columns each side), shelves in row 4; a packed block over rows 2-6
    # and map columns 5-8, where row 4's shelves leave 2 open tiles (both packed)
    rows = ["." * 14] * 4 + ["..@@@.@@.@@@.."] + ["." * 14] * 5
    T = 100
    visits = np.zeros((10, 14), dtype=np.uint32)
    visits[2:7, 5:9] = 95
    visits[4, [5, 6, 7, 8]] = [95, 0, 0, 95]  # shelves at 6, 7 (never visited); open 5 and 8
    visits[9, 2] = 99  # one packed tile alone: a tenth of its row, a ninth of its column
    got = traffic_map.jam_extent(rows, visits, T)
    # rows 2, 3, 5, 6: 4 of 10 open storage tiles packed; row 4: both of its 2 open ones
    assert got["jam_rows"] == [2, 6, 5]
    # columns 5 and 8 are packed in 5 of 10 rows; 6 and 7 in 4 of 9 open rows; column 2 in 1 of 9
    assert got["jam_cols"] == [5, 8, 4]
    nothing = traffic_map.jam_extent(rows, np.zeros((10, 14), dtype=np.uint32), T)
    assert nothing == {"jam_rows": None, "jam_cols": None}
