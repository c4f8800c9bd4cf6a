"""benchmarks/memo_similarity.py pairs each repair's Δ with the exact score of the layout it
returned (the memo keys repairs and exact runs differently), and says so when there is no memo."""

import numpy as np

from benchmarks.memo_similarity import main, pairs
from nca_qd.scoring.keys import layout_key


def test_each_delta_is_paired_with_its_own_layouts_score(tmp_path):
    layouts = np.stack([np.full((3, 4), v, np.int8) for v in range(3)])
    found = np.array([True, True, False])
    # exact scores held for layouts 2 (not found: ignored) and 1, in another order, and for one
    # layout no repair returned
    other = np.full((3, 4), 9, np.int8)
    np.savez(
        tmp_path / "eval_memo.npz",
        exact_keys=np.stack(
            [np.frombuffer(layout_key(x), np.uint8) for x in (layouts[2], other, layouts[1])]
        ),
        exact_throughput=np.array([[9.0, 9.0], [8.0, 8.0], [5.0, 7.0]]),
        repair_found=found,
        repair_layouts=layouts,
        repair_similarity=np.array([0.5, 0.75, 0.25]),
    )
    delta, score = pairs(tmp_path)
    assert delta.tolist() == [0.75] and score.tolist() == [6.0]


def test_a_run_without_a_memo_is_one_line_and_exit_2(tmp_path, capsys):
    assert main([str(tmp_path)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "no eval_memo.npz" in err
