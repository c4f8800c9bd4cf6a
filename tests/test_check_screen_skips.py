"""The screen-skip check (benchmarks/check_screen_skips.py): which memo layouts count as skipped,
and the elite each one faced, rebuilt from the memo's exact entries of earlier iterations."""

from __future__ import annotations

import math

import numpy as np

from benchmarks import check_screen_skips as css
from nca_qd.scoring.keys import layout_key


def _memo():
    lays = np.zeros((5, 3, 4), np.int8)
    for i in range(5):
        lays[i].flat[i] = 1  # five distinct repaired layouts
    exact = [0, 1, 3]  # layouts 0, 1, 3 were run exactly; 2 and 4 were skipped
    return {
        "repair_layouts": lays,
        "repair_found": np.array([True, True, True, True, True]),
        "repair_iteration": np.array([1, 2, 5, 3, 2]),
        "exact_keys": np.array([np.frombuffer(layout_key(lays[i]), np.uint8) for i in exact]),
        "exact_throughput": np.array([[4.0] * 5, [6.0] * 5, [9.0] * 5]),
        "exact_iteration": np.array([1, 2, 3]),
    }


def test_skipped_layouts_face_the_elite_of_earlier_iterations(monkeypatch):
    # cells: layouts 0, 1, 2, 3 share cell 7; layout 4 has cell 8 of its own
    cells_of = {0: 7, 1: 7, 2: 7, 3: 7, 4: 8}
    memo = _memo()
    monkeypatch.setattr(
        css,
        "_cells",
        lambda cfg, lays: np.array([cells_of[int(np.flatnonzero(l.ravel())[0])] for l in lays]),
    )
    got = {r["row"]: r for r in css.skipped_layouts(memo, None)}
    assert sorted(got) == [2, 4]
    # layout 2 came at iteration 5: cell 7 then held 4.0 (it. 1), 6.0 (it. 2), 9.0 (it. 3)
    assert got[2]["elite"] == 9.0 and got[2]["iteration"] == 5
    assert math.isinf(got[4]["elite"])  # its cell had no exact entry before iteration 2


def test_the_summary_counts_layouts_that_beat_their_elite():
    recs = [
        {"elite": 5.0, "mean": 5.5, "success": [True] * 5, "cpu_s": [1.0] * 5},
        {"elite": 5.0, "mean": 4.0, "success": [False] * 5, "cpu_s": [2.0] * 5},
        {"elite": -math.inf, "mean": 1.0, "success": [True] * 5, "cpu_s": [1.0] * 5},
    ]
    s = css.summarise(recs)
    assert (s["in_occupied_cells"], s["would_have_entered"], s["share"]) == (2, 1, 0.5)
    assert s["gains_over_elite"] == [0.5]
    lo, hi = s["share_95ci"]
    assert 0 < lo < 0.5 < hi < 1
