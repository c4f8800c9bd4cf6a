"""experiments.campaign: the arms of a comparison run one after another, in legs, each call
going on where the last stopped."""

from __future__ import annotations

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
