"""The fits behind the product's constants (nca_qd.calibration, ``experiments.calibrate``): the
screen-skip check (which memo layouts count as skipped, the elite each faced), the crowding rule
replayed on recorded runs against screening with it, the threshold and congested-model fits on
planted data, and the command on a shipped memo and on bad input."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest

from nca_qd.calibration import skips as css
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


# ------------------------------------------------------------------ crowding threshold
def _scenarios(n: int):
    from evaluate_helpers import HUMAN_9x14

    from nca_qd.sim.scenario import build_scenario

    return [build_scenario(HUMAN_9x14, "warehouse_even")] * n


def test_the_replayed_crowding_rule_gives_what_screening_with_it_gives():
    """One screening under RHCR's rule replayed at a threshold must give each run's verdict and
    throughput as screening with that threshold does (the calibration's grid rests on it)."""
    from nca_qd.calibration.crowding import MemoRuns, crowd_replay, replay_records, screen_in_chunks

    runs = MemoRuns("warehouse_even", 40, 200, [0, 1, 2])
    scens = _scenarios(2)
    moved = screen_in_chunks(scens, runs, "moved")
    crowd, tasks, stop0, ok0 = replay_records(moved, runs.T)
    for threshold in (2.0, 4.0, 30.0):
        ok, thr = crowd_replay(crowd, tasks, stop0, ok0, threshold)
        real = screen_in_chunks(scens, runs, "crowding", threshold)
        np.testing.assert_array_equal(ok, [[r.success for r in row] for row in real])
        np.testing.assert_allclose(thr, [[r.throughput for r in row] for row in real], rtol=1e-6)
    assert ok0.all() and not crowd_replay(crowd, tasks, stop0, ok0, 0.5)[0].any()  # some threshold bites


def test_the_best_threshold_is_the_one_that_agrees_with_rhcr():
    from nca_qd.calibration.crowding import GRID, best_threshold

    # four layouts, one run each, crowding constant over 200 checks: 10, 20, 25, 15
    level = np.array([10.0, 20.0, 25.0, 15.0])
    crowd = np.repeat(level[:, None, None], 200, axis=2)
    tasks = np.ones((4, 1, 1000))
    stop0, ok0 = np.full((4, 1), 1000), np.ones((4, 1), bool)
    rhcr_ok = np.array([True, False, False, True])  # congests where crowding >= 20
    best, agreement = best_threshold(crowd, tasks, stop0, ok0, rhcr_ok)
    assert agreement == 1.0 and 15.0 < best <= 20.0 and best in GRID


def test_the_scale_fit_recovers_a_planted_factor():
    from nca_qd.calibration.crowding import fit_scale

    screened = np.array([1.0, 2.0, 3.0, 4.0])
    assert fit_scale(screened, 1.3 * screened) == pytest.approx(1.3)


def test_the_congested_model_fit_recovers_planted_coefficients():
    from nca_qd.calibration.congested import fit

    rng = np.random.default_rng(0)
    n = 40
    flow = rng.uniform(5, 8, n)
    thr = rng.uniform(0.5, 4, (n, 5))
    stop = rng.uniform(0.1, 1, (n, 5))
    ok = rng.random((n, 5)) < 0.5
    ok[:5] = True  # layouts that flowed in every run are left out of the fit
    y = flow * (0.4 + 4.0 * thr.mean(1) / flow - 2.5 * stop.mean(1))
    y[:5] = -99.0  # (would spoil the fit were they used)
    np.testing.assert_allclose(fit(thr, ok, stop, flow, y), (0.4, 4.0, -2.5), atol=1e-9)


def test_the_threshold_calibration_runs_on_a_shipped_memo(capsys):
    """End to end on the shipped uneven search's memo, a handful of layouts: every line is
    there and the best threshold is one of the grid."""
    from experiments import calibrate

    memo = Path(__file__).resolve().parents[1] / "results/warehouse_uneven_a5/eval_memo.npz"
    assert calibrate.main(["fit=crowd_threshold", f"memo={memo}", "until=3", "limit=6"]) == 0
    lines = [json.loads(x) for x in capsys.readouterr().out.splitlines()]
    assert lines[0]["domain"] == "warehouse_uneven" and lines[0]["calibrate_on"] + lines[0]["check_on"] == 6
    assert lines[1]["calibration_best_threshold"] in set(np.arange(14.0, 30.01, 0.25).tolist())
    assert 0.5 < lines[1]["screen_scale"] < 5
    assert 0.5 < lines[2]["free_flow_efficiency"] <= 1.0
    checked = [x for x in lines if "majority_agreement" in x]
    # the best, the domain's configured threshold (warehouse_uneven.yaml: 21) and the default (17)
    assert {x["threshold"] for x in checked} >= {21.0, 17.0} and all(x["layouts"] == 3 for x in checked)


@pytest.mark.parametrize(
    "args, message",
    [
        ([], "fit must be one of crowd_threshold, crowd_drift, screen_skips, congested"),
        (["fit=crowd_threshold"], "give memo=<file>"),
        (["fit=crowd_threshold", "memo=/nonexistent.npz"], "memo=/nonexistent.npz: no such file"),
        (["fit=crowd_threshold", "memo=MEMO"], "give until=<the last iteration to calibrate on>"),
        (["fit=crowd_drift", "memo=MEMO", "from_iteration=-1"], "from_iteration must be an integer >= 0"),
        (["fit=screen_skips", "run_dir=/nonexistent"], "not a multi-agent run directory"),
        (["fit=screen_skips", "run_dir=RUN"], "give out=<a JSON-lines file>"),
        (
            ["fit=screen_skips", "run_dir=RUN", "out=/nonexistent/x.jsonl"],
            "folder /nonexistent does not exist",
        ),
        (["fit=screen_skips", "run_dir=RUN", "out=OUT", "replay=[0]"], "replay must be a list of positive"),
        (["fit=congested"], "give maps=<a folder with the paper's human_33x36.json"),
    ],
)
def test_bad_calibration_input_is_one_line_and_exit_2(args, message, tmp_path):
    import subprocess
    import sys

    root = Path(__file__).resolve().parents[1]
    subs = {
        "MEMO": str(root / "results/warehouse_uneven_a5/eval_memo.npz"),
        "RUN": str(root / "results/warehouse_uneven_a5"),
        "OUT": str(tmp_path / "skips.jsonl"),
    }
    argv = [
        a.split("=")[0] + "=" + subs.get(a.split("=", 1)[1], a.split("=", 1)[1]) if "=" in a else a
        for a in args
    ]
    res = subprocess.run(
        [sys.executable, "-m", "experiments.calibrate", *argv],
        capture_output=True,
        text=True,
        cwd=root,
        timeout=120,
    )
    assert res.returncode == 2, res.stderr
    lines = res.stderr.strip().splitlines()
    assert len(lines) == 1 and message in lines[0], res.stderr
