"""Whether a generator settles: the kinds of nca_qd.dynamics on layouts built to be of each kind,
the generator's trajectory against its plain generation, and the command on the shipped run."""

from __future__ import annotations

import sys
from pathlib import Path

import jax
import numpy as np
import pytest

from experiments import dynamics as dynamics_cli
from experiments.cli import main_guard
from nca_qd.dynamics import classify, count_misses, shifted_mismatch, summarise
from nca_qd.layouts.rules import CountRule
from nca_qd.nca import NCAGenerator

RNG = np.random.default_rng(0)
SHIPPED = Path(__file__).resolve().parents[1] / "results" / "warehouse_even_qd" / "cma_mae_a5_s0"


def test_shifted_mismatch_finds_the_move():
    a = RNG.integers(0, 3, (20, 24))
    b = np.roll(a, (1, -2), axis=(0, 1))  # a's content moved down 1, left 2
    m, dy, dx = shifted_mismatch(a, b, 2)
    assert (m, dy, dx) == (0.0, 1, -2)
    assert (a != b).mean() > 0.5  # unmoved, they differ in most cells


@pytest.mark.parametrize("kind", ["still", "travelling", "period_2", "other"])
def test_classify_names_each_kind(kind):
    a, b = RNG.integers(0, 3, (2, 30, 30))
    if kind == "still":
        seq = [a, a, a, a]
    elif kind == "travelling":
        seq = [np.roll(a, (0, i), axis=(0, 1)) for i in range(4)]
    elif kind == "period_2":
        seq = [a, b, a, b]
    else:
        seq = list(RNG.integers(0, 3, (4, 30, 30)))
    got = classify(np.stack(seq), 3)
    assert got["kind"] == kind


def test_share_swing_is_the_largest_change_of_a_tile_share():
    full = np.ones((10, 10), dtype=int)
    empty = np.zeros((10, 10), dtype=int)
    half = full.copy()
    half[:5] = 0
    got = classify(np.stack([full, empty, half]), 2)
    assert got["kind"] == "other"
    assert got["share_swing"] == pytest.approx(1.0)
    assert summarise(["still", "other", "other", "travelling"]) == {
        "still": 0.25,
        "travelling": 0.25,
        "period_2": 0.0,
        "other": 0.5,
    }


def test_trajectory_matches_generation_and_counts_ties():
    gen = NCAGenerator(n_tiles=3)
    flat = np.stack([np.asarray(gen.init_flat(jax.random.PRNGKey(i))) * 4 for i in range(3)])
    seed = RNG.integers(0, 3, (12, 11))
    layouts, tied = gen.trajectory(flat, seed, 7, 3)
    assert layouts.shape == (3, 4, 12, 11)
    for k in range(4):
        np.testing.assert_array_equal(layouts[:, k], np.asarray(gen.generate(flat, seed, 7 + k)))
    # all-zero weights: every channel outputs sigmoid(0) = 0.5, all cells tied
    _, tied0 = gen.trajectory(np.zeros((1, gen.n_params)), seed, 2, 2)
    assert tied0[0] == 1.0 and (tied >= 0).all() and (tied <= 1).all()


def test_count_misses_for_exact_and_lower_bound_rules():
    layout = np.zeros((4, 5), dtype=np.int32)
    layout[0, :3] = 1  # three of tile 1
    rules = (
        CountRule(frozenset({1}), "==", 4, "ones"),
        CountRule(frozenset({0, 1}), ">=", 10, "zeros or ones"),
        CountRule(frozenset({2}), ">=", 2, "twos"),
    )
    ones, both, twos = count_misses(layout, rules)
    assert (ones["got"], ones["miss"]) == (3, pytest.approx(0.25))
    assert (both["got"], both["miss"]) == (20, 0.0)  # more than the lower bound: no miss
    assert (twos["got"], twos["miss"]) == (0, 1.0)
    layout[1, :3] = 1  # six of tile 1: two too many is a miss too
    assert count_misses(layout, rules[:1])[0]["miss"] == pytest.approx(0.5)


def _cli(argv, monkeypatch):
    monkeypatch.setattr(sys, "argv", ["prog", *argv])
    with pytest.raises(SystemExit) as exc:
        main_guard(dynamics_cli.main)()
    return exc.value.code


@pytest.mark.parametrize(
    "argv, expect",
    [
        ([], "give run_dir"),
        (["run_dir=/nonexistent"], "does not exist"),
        (["run_dir=.", "size=big"], "size must be train or eval"),
        (["run_dir=.", "extra=1"], "extra must be an integer >= 2"),
        (["run_dir=.", "top=0"], "top must be a positive integer"),
        (["run_dir=.", "out=/nonexistent/d.csv"], "does not exist"),
    ],
)
def test_bad_input_is_one_line_and_exit_2(argv, expect, monkeypatch, capsys):
    assert _cli(argv, monkeypatch) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and expect in err[0]


@pytest.mark.skipif(not SHIPPED.is_dir(), reason="shipped run not present")
def test_the_command_classifies_the_shipped_archive(tmp_path, monkeypatch, capsys):
    out = tmp_path / "d.csv"
    argv = [f"run_dir={SHIPPED}", "top=3", f"out={out}"]
    assert _cli(argv, monkeypatch) == 0
    text = capsys.readouterr().out
    assert "10 best (3, 33x32, C=50..54)" in text
    rows = out.read_text().splitlines()
    assert rows[0].startswith("cell,objective,kind") and len(rows) == 4
    # the shipped best generator (cell 4472) alternates between two layouts at S: nearly every
    # cell changes from C to C + 1 and comes back at C + 2
    first = dict(zip(rows[0].split(","), rows[1].split(",")))
    assert first["cell"] == "4472" and first["kind"] == "period_2"
    assert float(first["changed_1"]) > 0.99 and float(first["changed_2"]) < 0.02
    # its shelves before repair, counted here on its plain generation at C = 50 (the '@' tile of
    # the full map): the warehouse at S needs 240
    assert "shelves == 240 before repair, 10 best (3, 33x32" in text
    from nca_qd.domains import make_domain
    from nca_qd.evaluation.layouts import load_run
    from nca_qd.pipeline import make_generator

    run_cfg, archive = load_run(SHIPPED)
    domain = make_domain(run_cfg["domain"])
    region = make_generator(domain).generate(
        np.asarray(archive["genotypes"])[[4472]], domain.seed((33, 32)), 50
    )
    full = domain.assemble(np.asarray(region)[0])
    assert int(first["shelves"]) == int((full == domain.layout_tiles.index("@")).sum())
    assert float(first["count_miss"]) == pytest.approx(abs(int(first["shelves"]) - 240) / 240, abs=1e-5)
