"""benchmarks.band_splice: rows copied where asked and nowhere else, the kept columns stay the
target's, and bad input is one line, exit 2."""

import json

import pytest

from benchmarks import band_splice
from nca_qd.io import MapFile, load_map, save_map


def _maps(tmp_path):
    target = ["ab" + "." * 6 + "cd" for _ in range(6)]
    source = [f"xy{i}{i}{i}{i}{i}{i}zw" for i in range(6)]
    save_map(tmp_path / "t.json", MapFile("t", target))
    save_map(tmp_path / "s.json", MapFile("s", source))
    return target, source


def test_rows_are_copied_with_a_shift_and_the_frame_kept(tmp_path, capsys):
    target, source = _maps(tmp_path)
    out = tmp_path / "o.json"
    argv = [str(tmp_path / "t.json"), str(tmp_path / "s.json"), "--copy", "1-2:2-3", "--copy", "5-5:0-0"]
    assert band_splice.main([*argv, "--keep-cols", "2", "--out", str(out)]) == 0
    rows = load_map(out).rows
    assert rows[1] == "ab222222cd" and rows[2] == "ab333333cd" and rows[5] == "ab000000cd"
    assert [rows[i] for i in (0, 3, 4)] == [target[i] for i in (0, 3, 4)]  # untouched
    assert json.loads(capsys.readouterr().out)["shelves"] == 0
    assert band_splice.main([*argv, "--out", str(out)]) == 0  # keep-cols 0: whole rows
    assert load_map(out).rows[1] == source[2]


@pytest.mark.parametrize(
    "copy, expect",
    [
        (["--copy", "1-3:0-1"], "same number of rows"),
        (["--copy", "4-6:0-2"], "rows run from 0 to 5"),
        (["--copy", "1-2:0-1", "--copy", "2-3:4-5"], "overlap at target rows [2]"),
        (["--copy", "a-b"], "expected T0-T1:S0-S1"),
        (["--copy", "0-1:0-1", "--keep-cols", "5"], "--keep-cols must be from 0 to 4"),
    ],
)
def test_bad_input_is_one_line_and_exit_2(tmp_path, capsys, copy, expect):
    _maps(tmp_path)
    argv = [str(tmp_path / "t.json"), str(tmp_path / "s.json"), *copy, "--out", str(tmp_path / "o.json")]
    assert band_splice.main(argv) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and expect in err[0], err
    assert not (tmp_path / "o.json").exists()
