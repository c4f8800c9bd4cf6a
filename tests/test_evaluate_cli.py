"""experiments.evaluate from the command line: one-line errors (exit 2) on bad input, and the
settings that come from the run unless the command overrides them."""

from __future__ import annotations

import sys

import numpy as np
import pytest
from evaluate_helpers import TINY_RUN, make_run
from omegaconf import OmegaConf

from experiments import evaluate as evaluate_cli
from experiments.cli import compose_config, main_guard
from nca_qd.errors import NcaQdError


def run_cli(argv, monkeypatch):
    monkeypatch.setattr(sys, "argv", ["prog", *argv])
    with pytest.raises(SystemExit) as exc:
        main_guard(evaluate_cli.main)()
    return exc.value.code


@pytest.fixture(scope="module")
def tiny_run(tmp_path_factory):
    return make_run(tmp_path_factory.mktemp("bad") / "run")


@pytest.mark.parametrize(
    "case, expect",
    [
        ("missing", "does not exist"),
        ("not_a_run", "not a run directory"),
        ("maze", "maze run: experiments.evaluate supports only"),
        ("dsage", "is a DSAGE run: its layouts exist at the training size only, so select.by=s_eval"),
        ("mismatch", "domain=manufacturing given, but"),
        ("empty", "the result archive is empty"),
        ("no_run_dir", "give run_dir"),
        ("exact_over_runs", "exact.train (9) exceeds runs.train (3)"),
        ("dask", "Dask scheduler"),
        ("stray_size", "sizes.agents names 50x50, not a size of the curve"),
        ("not_a_map", "sizes.n_shelves must map sizes to values"),
        ("select_by", "select.by must be s or s_eval, got 'best'"),
        ("select_pool", "elites (3) exceeds select.pool (2)"),
        ("select_list", "elites must be a count"),
        ("screen_reuse", "screen.reuse must be true or false, got 'sometimes'"),
        ("shelves_count", "n_shelves.eval must be an integer >= 1, got 0"),
        ("shelves_manufacturing", "n_shelves.eval: manufacturing has no shelves"),
        ("draws_count", "baselines.tiling_draws must be an integer >= 1, got 0"),
        ("draws_no_ties", "baselines.tiling_draws=3 needs repair.tie_break=random"),
    ],
)
def test_bad_input_is_one_line_and_exit_2(case, expect, tmp_path, tiny_run, monkeypatch, capsys):
    argv = [f"run_dir={tiny_run}", f"out={tmp_path / 'o'}"]
    if case == "missing":
        argv[0] = f"run_dir={tmp_path / 'nope'}"
    elif case == "not_a_run":
        argv[0] = f"run_dir={tmp_path}"
    elif case == "maze":
        argv[0] = f"run_dir={make_run(tmp_path / 'maze', ['domain=maze'])}"
    elif case == "dsage":
        argv[0] = f"run_dir={make_run(tmp_path / 'dsage', [*TINY_RUN, 'algo=dsage'])}"
        argv.append("select.by=s_eval")
    elif case == "mismatch":
        argv.append("domain=manufacturing")
    elif case == "empty":
        argv[0] = f"run_dir={make_run(tmp_path / 'empty', empty=True)}"
    elif case == "no_run_dir":
        argv = []
    elif case == "exact_over_runs":
        argv += ["runs.train=3", "exact.train=9"]
    elif case == "stray_size":
        argv.append("sizes.agents={50x50: [10]}")
    elif case == "not_a_map":
        argv.append("sizes.n_shelves=[1,2]")
    elif case == "select_by":
        argv.append("select.by=best")
    elif case == "select_pool":
        argv += ["select.by=s_eval", "select.pool=2", "elites=3"]
    elif case == "select_list":
        argv += ["select.by=s_eval", "elites=[3,7]"]
    elif case == "screen_reuse":
        argv.append("screen.reuse=sometimes")
    elif case == "shelves_count":
        argv.append("n_shelves.eval=0")
    elif case == "shelves_manufacturing":
        argv[0] = f"run_dir={make_run(tmp_path / 'mf', ['domain=manufacturing'])}"
        argv.append("n_shelves.eval=2500")
    elif case == "draws_count":
        argv.append("baselines.tiling_draws=0")
    elif case == "draws_no_ties":  # every draw would be the same layout
        argv += ["baselines.tiling_draws=3", "repair.tie_break=none"]
    elif case == "dask":
        argv += ["eval.scheduler=tcp://127.0.0.1:9", "eval.connect_timeout_s=1"]
    code = run_cli(argv, monkeypatch)
    err = capsys.readouterr().err.strip()
    assert code == 2
    assert len(err.splitlines()) == 1 and "Traceback" not in err, err
    assert err.startswith("error: ") and expect in err, err
    assert not (tmp_path / "o").exists()


def test_n_shelves_sets_the_shelf_count_of_its_size_only(tiny_run):
    """n_shelves.eval (the paper's released S_eval layouts hold 2,500 shelves where its table
    says 2,250) changes N_s at S_eval; S keeps the run's count."""
    from nca_qd.evaluation.plan import Plan, validated

    e = validated(
        OmegaConf.to_container(compose_config("evaluate", [f"run_dir={tiny_run}", "n_shelves.eval=30"]))
    )
    d = OmegaConf.to_container(compose_config("run", TINY_RUN).domain, resolve=True)
    plan = Plan(e, d, "warehouse_even")
    assert plan.repair_options(plan.s_eval)["n_shelves"] == 30
    assert plan.repair_options(plan.s_train)["n_shelves"] == 12
    e_default = validated(OmegaConf.to_container(compose_config("evaluate", [f"run_dir={tiny_run}"])))
    plan = Plan(e_default, d, "warehouse_even")
    assert plan.repair_options(plan.s_eval)["n_shelves"] == 24


def test_exact_runs_go_to_the_curve_points_named_and_no_others(tiny_run):
    """sweep.<size>.exact_agents: exact verdicts on a few points of a curve (issue 55 asks for
    three per curve) without exact runs at every point; null keeps every point exact."""
    from nca_qd.evaluation.plan import Plan, validated
    from nca_qd.evaluation.records import EvalLayout

    d = OmegaConf.to_container(compose_config("run", TINY_RUN).domain, resolve=True)

    def exact_at(cmd: list[str]) -> dict[int, int]:
        e = validated(OmegaConf.to_container(compose_config("evaluate", [f"run_dir={tiny_run}", *cmd])))
        plan = Plan(e, d, "warehouse_even")
        lay = EvalLayout("k", "NCA", "nca", "9x14", "train", np.zeros(plan.s_train, np.int32), cell=3)
        return {r.n_agents: r.exact_runs for r in plan.requests({"k": lay}) if r.purpose == "sweep_train"}

    base = ["sweep.train.agents=[4,6,8]", "exact.sweep_train=2"]
    assert exact_at(base) == {4: 2, 6: 2, 8: 2}
    assert exact_at([*base, "sweep.train.exact_agents=[4,8]"]) == {4: 2, 6: 0, 8: 2}
    with pytest.raises(NcaQdError, match="sweep.train.exact_agents names 5, not a point of the curve"):
        exact_at([*base, "sweep.train.exact_agents=[5]"])


def test_repair_tie_break_comes_from_the_run_unless_this_command_overrides_it(tiny_run):
    """A run repaired with tie_break=none is evaluated with none (its own repair); the
    command's repair.tie_break=random overrides it at every size."""
    from nca_qd.evaluation.plan import Plan, validated

    def opts(cmd: list[str], run: list[str]) -> list[str]:
        e = validated(OmegaConf.to_container(compose_config("evaluate", [f"run_dir={tiny_run}", *cmd])))
        d = OmegaConf.to_container(compose_config("run", [*TINY_RUN, *run]).domain, resolve=True)
        plan = Plan(e, d, "warehouse_even")
        return [plan.repair_options(s)["tie_break"] for s in (plan.s_train, plan.s_eval)]

    assert opts([], ["domain.repair.tie_break=none"]) == ["none", "none"]
    assert opts([], []) == ["random", "random"]  # the domains' default
    assert opts(["repair.tie_break=random"], ["domain.repair.tie_break=none"]) == ["random", "random"]


def test_too_many_agents_names_the_layout(tiny_run, tmp_path, maps, monkeypatch, capsys):
    code = run_cli(
        [
            f"run_dir={tiny_run}",
            f"out={tmp_path / 'o'}",
            "sweep.train.agents=[500]",
            "sweep.eval.agents=[]",
            "sizes.shapes=[]",
            "sizes.include_main=false",
            "baselines.tiling=false",
            "eval.workers=0",
            "progress=false",
        ],
        monkeypatch,
    )
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and not any("Traceback" in l for l in err)
    assert err[-1].startswith("error: ") and "500 agents but only" in err[-1]
    assert "(9x14)" in err[-1] and "lower the agent counts" in err[-1]
    # no output, only the repairs made before the check, which the corrected command reuses
    # (packed when the evaluation stopped)
    assert sorted(p.name for p in (tmp_path / "o").iterdir()) == ["repairs.jsonl.gz"]
