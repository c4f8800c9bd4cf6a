"""experiments.campaign: the arms of a comparison run one after another, in legs, each call
going on where the last stopped."""

from __future__ import annotations

import csv
from pathlib import Path

import pytest
from omegaconf import OmegaConf
from test_scoring import TINY_WAREHOUSE

from nca_qd.errors import NcaQdError


def test_a_campaign_runs_its_arms_in_legs_and_goes_on_where_it_stopped(tmp_path, capsys, monkeypatch):
    """experiments.campaign: arms in order, each in <root>/<arm>; a call whose time runs out
    exits 75 and the next call resumes that arm and starts the next; finished arms are
    skipped; status reports each arm."""
    from experiments import campaign

    args = [a for a in TINY_WAREHOUSE if "improve_windows" not in a]
    common = [a for a in args if a.startswith("domain")] + ["eval.workers=0", "output.pictures=false"]
    qd = [a for a in args if a.startswith("qd.")] + ["qd.n_evals=12"]
    plan = tmp_path / "plan.yaml"
    plan.write_text(
        f"root: {tmp_path / 'arms'}\ncommon: {common}\n"
        f"arms:\n  a_s0: {[*qd, 'seed=0']}\n  a_s1: {[*qd, 'seed=1']}\n"
    )
    assert campaign.main([f"plan={plan}", "status=true"]) == 0
    assert capsys.readouterr().out.splitlines() == ["a_s0: not started", "a_s1: not started"]
    monkeypatch.setattr(campaign, "MIN_LEG_S", 0.0)
    assert campaign.main([f"plan={plan}", "leg_seconds=1"]) == 75  # one iteration, then the leg ends
    first = campaign.progress(tmp_path / "arms" / "a_s0")
    assert first["state"] == "started" and 0 < first["evaluations"] < 12
    assert campaign.main([f"plan={plan}"]) == 0
    for arm in ("a_s0", "a_s1"):
        p = campaign.progress(tmp_path / "arms" / arm)
        assert p["state"] == "finished" and p["evaluations"] == 12
    seeds = [OmegaConf.load(tmp_path / "arms" / a / "config.yaml").seed for a in ("a_s0", "a_s1")]
    assert seeds == [0, 1]
    capsys.readouterr()
    assert campaign.main([f"plan={plan}"]) == 0  # nothing left to run
    assert "every arm" in capsys.readouterr().out


def test_a_bad_campaign_plan_is_one_clear_error(tmp_path):
    from experiments import campaign

    with pytest.raises(NcaQdError, match="no such plan"):
        campaign.main(["plan=nonexistent"])
    bad = tmp_path / "bad.yaml"
    bad.write_text("root: x\narms:\n  a: [run_dir=elsewhere]\n")
    with pytest.raises(NcaQdError, match="run_dir, resume and leg_seconds are the campaign's"):
        campaign.main([f"plan={bad}"])
    with pytest.raises(NcaQdError, match="leg_seconds must be a positive number"):
        campaign.main([f"plan={bad}", "leg_seconds=0"])


def test_a_campaign_evaluates_each_finished_arm_with_the_plans_protocol(tmp_path, capsys, monkeypatch):
    """A plan with ``evaluate:`` evaluates an arm once its search has finished (into
    <arm>/evaluation, with the plan's overrides), reports it in status, and skips it after."""
    from experiments import campaign

    args = [a for a in TINY_WAREHOUSE if "improve_windows" not in a]
    common = [a for a in args if a.startswith("domain")] + ["eval.workers=0", "output.pictures=false"]
    qd = [a for a in args if a.startswith("qd.")] + ["qd.n_evals=6", "seed=0"]
    evaluate = [
        "T=30",
        "runs.train=2",
        "runs.eval=1",
        "exact.train=1",
        "exact.eval=0",
        "sweep.train.agents=[]",
        "sweep.eval.agents=[]",
        "sizes.shapes=[]",
        "baselines.human=false",
        "eval.workers=0",
        "progress=false",
    ]
    plan = tmp_path / "plan.yaml"
    plan.write_text(f"root: {tmp_path / 'arms'}\ncommon: {common}\narms:\n  a: {qd}\nevaluate: {evaluate}\n")
    assert campaign.main([f"plan={plan}"]) == 0
    run_dir = tmp_path / "arms" / "a"
    assert campaign.progress(run_dir)["state"] == "finished" and campaign.evaluated(run_dir)
    with (run_dir / "evaluation" / "summary.csv").open() as fh:
        rows = list(csv.DictReader(fh))
    # the plan's protocol: at S two runs, one of them exact; at S_eval one (screened)
    runs = {(r["kind"], r["which"], r["simulator"]): r["runs"] for r in rows}
    assert runs[("nca", "train", "rhcr")] == "1" and runs[("nca", "train", "screen")] == "2"
    assert runs[("nca", "eval", "screen")] == "1" and runs.get(("nca", "eval", "rhcr"), "0") in ("0", "")
    assert "evaluated" in capsys.readouterr().out
    assert campaign.main([f"plan={plan}", "status=true"]) == 0
    assert capsys.readouterr().out.strip().endswith(", evaluated")
    assert campaign.main([f"plan={plan}"]) == 0  # evaluated: nothing left
    assert "has finished and been evaluated" in capsys.readouterr().out
    # the plan asks more later: the arm counts as evaluated only with the plan's settings
    assert campaign.evaluated(run_dir, evaluate) and campaign.evaluated(run_dir, ["sweep.train.agents=[]"])
    assert not campaign.evaluated(run_dir, [*evaluate, "runs.train=3"])
    assert not campaign.evaluated(run_dir, ["sweep.train.exact_agents=[10]"])
    assert not campaign.evaluated(run_dir, ["no.such.key=1"])
    # a key given twice holds its last value, as on the command line (an arm's own overrides
    # after the plan's: the MAP-Elites arms' tables-only evaluation)
    assert campaign.evaluated(run_dir, [*evaluate, "runs.train=3", "runs.train=2"])
    assert not campaign.evaluated(run_dir, [*evaluate, "runs.train=2", "runs.train=3"])
    longer = ["T=40", *evaluate[1:]]
    plan.write_text(f"root: {tmp_path / 'arms'}\ncommon: {common}\narms:\n  a: {qd}\nevaluate: {longer}\n")
    assert campaign.main([f"plan={plan}", "status=true"]) == 0
    assert "not yet with the plan's evaluate settings" in capsys.readouterr().out
    assert campaign.main([f"plan={plan}"]) == 0  # evaluated again, now with T=40
    assert OmegaConf.load(run_dir / "evaluation" / "evaluate_config.yaml").T == 40


def test_an_evaluation_cut_by_the_calls_time_ends_the_leg(tmp_path, monkeypatch):
    """The call's time runs out inside an evaluation: it is stopped as by Ctrl-C (its finished
    runs kept) and the campaign exits 75 at once, not when the evaluation would have ended."""
    import time

    from experiments import campaign

    def slow(argv):
        time.sleep(30)
        return 0

    monkeypatch.setattr(campaign, "evaluate_main", slow)
    t0 = time.monotonic()
    assert campaign._evaluate("a", tmp_path, [], 0.2) == 75
    assert time.monotonic() - t0 < 5
    monkeypatch.setattr(campaign, "evaluate_main", lambda argv: 0)
    assert campaign._evaluate("a", tmp_path, [], None) == 0


def test_a_plans_evaluation_may_not_set_where_it_writes(tmp_path):
    from experiments import campaign

    bad = tmp_path / "bad.yaml"
    bad.write_text("root: x\narms:\n  a: [seed=0]\nevaluate: [out=elsewhere]\n")
    with pytest.raises(NcaQdError, match="run_dir, out and records_from are the campaign's"):
        campaign.main([f"plan={bad}"])
    bad.write_text("root: x\narms:\n  a: [seed=0]\nevaluate: T=30\n")
    with pytest.raises(NcaQdError, match="evaluate must be a list of key=value"):
        campaign.main([f"plan={bad}"])


def test_an_interrupted_campaign_says_to_call_it_again(capsys, monkeypatch):
    """Ctrl-C or SIGTERM in a campaign (in a search or an evaluation) exits 130 with the way
    on: the same campaign command, not a search's resume= (an evaluation has no checkpoint)."""
    import sys

    from experiments import campaign
    from experiments.cli import main_guard

    def interrupted(argv):
        raise KeyboardInterrupt

    monkeypatch.setattr(sys, "argv", ["campaign", "plan=warehouse_even_qd"])
    with pytest.raises(SystemExit) as exc:
        main_guard(interrupted, campaign.INTERRUPTED)()
    err = capsys.readouterr().err
    assert exc.value.code == 130
    assert "experiments.campaign" in err and "resume=" not in err


def test_an_arms_evaluation_draws_on_the_other_arms_records(tmp_path, monkeypatch):
    """The campaign hands each evaluation the other arms' evaluation folders (records_from),
    through the command line as a user would type it: the human baselines, the same runs in
    every arm, are simulated once for the comparison."""
    from experiments import campaign
    from experiments.cli import compose_config

    root = tmp_path / "root with space"
    for arm in ("a_s0", "b_s0", "c_s0", "not_an_arm"):
        (root / arm).mkdir(parents=True)
    for arm in ("a_s0", "c_s0", "not_an_arm"):
        (root / arm / "evaluation").mkdir()
    arms = ["a_s0", "b_s0", "c_s0"]
    seen = []
    monkeypatch.setattr(campaign, "evaluate_main", lambda argv: seen.append(argv) or 0)
    assert campaign._evaluate("b_s0", root / "b_s0", ["T=30"], None, arms) == 0
    cfg = compose_config("evaluate", seen[0])
    assert list(cfg.records_from) == [str(root / "a_s0" / "evaluation"), str(root / "c_s0" / "evaluation")]
    assert cfg.T == 30 and cfg.run_dir == str(root / "b_s0")
    seen.clear()
    assert campaign._evaluate("a_s0", root / "a_s0", [], None, arms) == 0  # not its own folder
    assert list(compose_config("evaluate", seen[0]).records_from) == [str(root / "c_s0" / "evaluation")]


def test_an_arm_may_add_to_the_plans_evaluation(tmp_path):
    """evaluate_arms: an arm's own overrides after the plan's evaluate (the MAP-Elites and
    CMA-ES arms need no curves); only for arms of the plan, and only beside evaluate."""
    from experiments import campaign

    plan = tmp_path / "plan.yaml"
    plan.write_text(
        "root: x\narms:\n  a: [seed=0]\n  b: [seed=1]\nevaluate: [T=30]\n"
        "evaluate_arms:\n  b: ['sweep.eval.agents=[]', exact.sweep_eval=0]\n"
    )
    evaluate = campaign.load_plan(str(plan)).evaluate
    assert evaluate == {"a": ["T=30"], "b": ["T=30", "sweep.eval.agents=[]", "exact.sweep_eval=0"]}
    for bad, match in (
        ("evaluate: [T=30]\nevaluate_arms:\n  c: [T=40]\n", "must map arms of the plan"),
        ("evaluate_arms:\n  a: [T=40]\n", "adds to evaluate"),
        ("evaluate: [T=30]\nevaluate_arms:\n  a: T=40\n", "must be a list of key=value"),
        ("evaluate: [T=30]\nevaluate_arms:\n  a: ['records_from=[x]']\n", "records_from are the campaign's"),
    ):
        plan.write_text("root: x\narms:\n  a: [seed=0]\n" + bad)
        with pytest.raises(NcaQdError, match=match):
            campaign.load_plan(str(plan))


def _recording_evaluation(seen: list[list[str]]):
    """A stand-in for experiments.evaluate's main: records its argv in ``seen`` and writes what a
    finished evaluation leaves (its config, summary.csv) where the real one would."""
    from experiments.cli import compose_config

    def fake_evaluate(argv):
        seen.append(argv)
        cfg = compose_config("evaluate", argv)
        out = Path(cfg.out or Path(cfg.run_dir) / "evaluation")
        out.mkdir(parents=True, exist_ok=True)
        OmegaConf.save(cfg, out / "evaluate_config.yaml")
        (out / "summary.csv").write_text("domain\nwarehouse_even\n")
        return 0

    return fake_evaluate


def _finished_arms(root: Path, arms) -> None:
    """Arm folders under ``root`` whose searches have finished (10 of 10 evaluations)."""
    for arm in arms:
        (root / arm).mkdir(parents=True)
        (root / arm / "config.yaml").write_text("qd:\n  n_evals: 10\n")
        (root / arm / "metrics.csv").write_text("iteration,evaluations,qd_score,coverage\n1,10,5,0.1\n")


def test_a_plans_other_evaluations_run_after_every_arm_into_their_own_folders(tmp_path, monkeypatch, capsys):
    """evaluate_also: {tag: [overrides]}: once every arm has finished and been evaluated, each
    arm is evaluated again into <arm>/evaluation_<tag> with its evaluate overrides and the
    tag's, drawing on its own main evaluation's records and the other arms'; done once."""
    from experiments import campaign
    from experiments.cli import compose_config

    root = tmp_path / "arms"
    seen: list[list[str]] = []

    fake_evaluate = _recording_evaluation(seen)
    _finished_arms(root, ("a", "b"))
    monkeypatch.setattr(campaign, "evaluate_main", fake_evaluate)
    plan = tmp_path / "plan.yaml"
    plan.write_text(
        f"root: {root}\narms:\n  a: [seed=0]\n  b: [seed=1]\nevaluate: [T=30]\n"
        "evaluate_also:\n  ns2500: [n_shelves.eval=2500, runs.train=1]\n"
    )
    assert campaign.main([f"plan={plan}"]) == 0
    # the main evaluations first, then the other ones, arm by arm
    outs = [compose_config("evaluate", argv).out for argv in seen]
    assert outs == [None, None, str(root / "a" / "evaluation_ns2500"), str(root / "b" / "evaluation_ns2500")]
    last = compose_config("evaluate", seen[-1])
    assert last.T == 30 and last.n_shelves.eval == 2500 and last.runs.train == 1
    assert list(last.records_from) == [
        str(root / "a" / "evaluation"),
        str(root / "b" / "evaluation"),
        str(root / "a" / "evaluation_ns2500"),
    ]
    # an evaluation made by hand beside them (other settings) lends its records too
    (root / "a" / "evaluation_draws").mkdir()
    handed: list[list[str]] = []
    monkeypatch.setattr(campaign, "evaluate_main", lambda argv: handed.append(argv) or 0)
    assert campaign._evaluate("b", root / "b", [], None, ["a", "b"], "evaluation_ns2500") == 0
    assert list(compose_config("evaluate", handed[0]).records_from)[-2:] == [
        str(root / "a" / "evaluation_ns2500"),
        str(root / "a" / "evaluation_draws"),
    ]
    (root / "a" / "evaluation_draws").rmdir()
    monkeypatch.setattr(campaign, "evaluate_main", fake_evaluate)
    capsys.readouterr()
    assert campaign.main([f"plan={plan}", "status=true"]) == 0
    assert capsys.readouterr().out.splitlines()[0].endswith(", evaluated; evaluation_ns2500 done")
    seen.clear()
    assert campaign.main([f"plan={plan}"]) == 0 and seen == []  # nothing left
    for bad, match in (
        ("evaluate_also:\n  x: [T=1]\n", "adds to evaluate"),
        ("evaluate: [T=30]\nevaluate_also:\n  Bad-Tag: [T=1]\n", "lower-case letters"),
        ("evaluate: [T=30]\nevaluate_also:\n  x: [out=elsewhere]\n", "the campaign's to set"),
        ("evaluate: [T=30]\nevaluate_also: [T=1]\n", "must map tags"),
    ):
        plan.write_text(f"root: {root}\narms:\n  a: [seed=0]\n" + bad)
        with pytest.raises(NcaQdError, match=match):
            campaign.load_plan(str(plan))


def test_a_plans_other_evaluation_may_be_kept_to_some_arms(tmp_path, monkeypatch, capsys):
    """evaluate_also_arms: {tag: [arm, ...]}: the tag's evaluation runs for the arms named only
    (a row of the comparison that the other arms do not have costs them nothing); status says
    nothing of it for the others; a tag or an arm the plan lacks is one clear error."""
    from experiments import campaign
    from experiments.cli import compose_config

    root = tmp_path / "arms"
    seen: list[list[str]] = []

    fake_evaluate = _recording_evaluation(seen)
    _finished_arms(root, ("a", "b", "c"))
    monkeypatch.setattr(campaign, "evaluate_main", fake_evaluate)
    plan = tmp_path / "plan.yaml"
    head = f"root: {root}\narms:\n  a: [seed=0]\n  b: [seed=1]\n  c: [seed=2]\nevaluate: [T=30]\n"
    also = "evaluate_also:\n  ns2500: [n_shelves.eval=2500]\n  short: [T=20]\n"
    plan.write_text(head + also + "evaluate_also_arms:\n  ns2500: [c, a]\n")
    assert campaign.load_plan(str(plan)).also_arms == {"ns2500": ["a", "c"], "short": ["a", "b", "c"]}
    assert campaign.main([f"plan={plan}"]) == 0
    outs = [compose_config("evaluate", argv).out for argv in seen]
    assert outs[:3] == [None, None, None]
    assert outs[3:] == [str(root / a / f"evaluation_{t}") for t, a in [("ns2500", "a"), ("ns2500", "c")]] + [
        str(root / a / "evaluation_short") for a in ("a", "b", "c")
    ]
    assert not (root / "b" / "evaluation_ns2500").exists()
    capsys.readouterr()
    assert campaign.main([f"plan={plan}", "status=true"]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert lines[0].endswith("evaluation_ns2500 done; evaluation_short done")
    assert "ns2500" not in lines[1] and lines[1].endswith("evaluation_short done")
    seen.clear()
    assert campaign.main([f"plan={plan}"]) == 0 and seen == []  # b is not owed an ns2500 evaluation
    for bad, match in (
        ("evaluate_also_arms:\n  other: [a]\n", "tags of evaluate_also"),
        ("evaluate_also_arms:\n  ns2500: [d]\n", "must list arms of the plan"),
        ("evaluate_also_arms:\n  ns2500: []\n", "must list arms of the plan"),
        ("evaluate_also_arms:\n  ns2500: a\n", "must list arms of the plan"),
    ):
        plan.write_text(head + also + bad)
        with pytest.raises(NcaQdError, match=match):
            campaign.load_plan(str(plan))
    plan.write_text(head + "evaluate_also_arms:\n  ns2500: [a]\n")
    with pytest.raises(NcaQdError, match="tags of evaluate_also"):
        campaign.load_plan(str(plan))
