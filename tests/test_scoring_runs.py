"""Short warehouse / manufacturing searches end to end (outputs, resume, a loaded machine, bad
settings), and the scoring settings' one default each in the YAMLs."""

from __future__ import annotations

import csv
import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from scoring_helpers import TINY_WAREHOUSE

from nca_qd.scoring.backend import LocalBackend
from nca_qd.scoring.settings import ScoringConfig

REPO = Path(__file__).resolve().parents[1]


# ------------------------------------------------------------------------------ full runs
def _run(args, timeout=600):
    env = {**os.environ, "JAX_PLATFORMS": "cpu"}
    return subprocess.run(
        [sys.executable, "-m", "experiments.run", *args],
        cwd=REPO,
        env=env,
        capture_output=True,
        text=True,
        timeout=timeout,
    )


def _run_here(args):
    """experiments.run's main in this process: the jitted programs compiled by earlier runs
    are reused (a subprocess per run spent most of its time starting JAX and recompiling)."""
    from experiments.run import main

    return main(list(args))


def test_tiny_warehouse_run_writes_outputs_resumes_identically_and_from_its_snapshot(tmp_path):
    """checkpoint.exact: the resumed leg replays the uninterrupted run bit for bit (the default
    compact checkpoint resumes it statistically: tests/test_checkpoint.py). The same leg's
    portable snapshot, alone with what results/<run>/ commits (config, metrics, memo), carries
    the run to its end as on a fresh clone."""
    import shutil

    from nca_qd.qd.checkpoint import read_checkpoint

    common = TINY_WAREHOUSE + ["eval.workers=0", "output.n_best=2", "checkpoint.exact=true"]
    assert _run_here(common + ["qd.n_evals=18", f"run_dir={tmp_path / 'full'}"]) == 0
    part = tmp_path / "part"
    snapshot_args = ["snapshot.enabled=true", "snapshot.exact_elites=1"]
    leg1 = common + ["qd.n_evals=12", "output.pictures=false", *snapshot_args, f"run_dir={part}"]
    assert _run_here(leg1) == 0
    snap, full = part / "snapshot.npz", part / "checkpoint.npz"
    assert snap.is_file() and snap.stat().st_size < full.stat().st_size
    arrays, meta = read_checkpoint(snap)
    assert meta["snapshot"] and arrays["res_exact"].sum() == 1  # the best elite stays float32
    assert arrays["res_restart_genotypes"].dtype == np.int8
    clone = tmp_path / "clone"
    clone.mkdir()
    for name in ("config.yaml", "metrics.csv", "eval_memo.npz", "snapshot.npz"):
        shutil.copy(part / name, clone / name)

    assert _run_here([f"resume={part}", "qd.n_evals=18"]) == 0
    for name in ("best_train_repaired.png", "best_eval_repaired.png", "archive_result.png", "curves.png"):
        assert (tmp_path / "full" / name).is_file(), name
    with open(tmp_path / "full" / "metrics.csv") as fh:
        rows = list(csv.DictReader(fh))
    assert [int(r["iteration"]) for r in rows] == [1, 2, 3]
    assert all(int(r["n_exact"]) <= int(r["n_valid"]) <= 6 for r in rows)
    assert int(rows[0]["n_exact"]) >= 1  # an empty result archive: its first layouts go exact
    a = np.load(tmp_path / "full" / "archive_result.npz")
    b = np.load(part / "archive_result.npz")
    np.testing.assert_array_equal(a["objective"], b["objective"])
    np.testing.assert_array_equal(a["genotypes"], b["genotypes"])
    assert (part / "eval_memo.npz").is_file()  # the resumed leg kept its memo

    assert _run_here([f"resume={clone}", "qd.n_evals=18"]) == 0
    with open(clone / "metrics.csv") as fh:
        assert [int(r["iteration"]) for r in csv.DictReader(fh)] == [1, 2, 3]
    c = np.load(clone / "archive_result.npz")
    assert np.isfinite(c["objective"]).all() and c["genotypes"].shape[0] == c["objective"].size


def test_a_loaded_machine_gives_the_same_warehouse_search(tmp_path, slow_clock):
    """The domain's own repair settings bound work, not time: three iterations of a warehouse
    search give the same metrics and archive when every clock reading the repair takes runs
    100 ms (a loaded machine, to the code) as on an idle machine."""
    from nca_qd import repair as repair_pkg
    from nca_qd.repair import neighbourhood

    args = [a for a in TINY_WAREHOUSE if "improve_windows" not in a]
    args += ["eval.workers=0", "output.pictures=false", "qd.n_evals=18"]
    assert _run_here(args + [f"run_dir={tmp_path / 'idle'}"]) == 0
    slow_clock(neighbourhood, repair_pkg)
    assert _run_here(args + [f"run_dir={tmp_path / 'loaded'}"]) == 0
    rows = {}
    for name in ("idle", "loaded"):
        with open(tmp_path / name / "metrics.csv") as fh:
            rows[name] = [
                {k: v for k, v in r.items() if "second" not in k and "time" not in k}
                for r in csv.DictReader(fh)
            ]
    assert len(rows["idle"]) == 3 and rows["idle"] == rows["loaded"]
    a, b = (np.load(tmp_path / name / "archive_result.npz") for name in ("idle", "loaded"))
    np.testing.assert_array_equal(a["objective"], b["objective"])
    np.testing.assert_array_equal(a["genotypes"], b["genotypes"])


@pytest.mark.parametrize(
    "args, message",
    [
        (["eval.exact=sometimes"], "eval.exact must be one of selective, all"),
        (["eval.screen_estimate=guess"], "eval.screen_estimate must be one of scaled, free_flow"),
        (["eval.phases=0"], "eval.phases must be an integer >= 1, got 0"),
        (
            ["eval.scheduler=tcp://127.0.0.1:9", "eval.connect_timeout_s=1"],
            "cannot reach the Dask scheduler at tcp://127.0.0.1:9",
        ),
    ],
)
def test_bad_eval_settings_get_one_line_and_exit_2(args, message, tmp_path):
    res = _run(TINY_WAREHOUSE + ["qd.n_evals=6", f"run_dir={tmp_path / 'r'}"] + args, timeout=120)
    assert res.returncode == 2
    lines = res.stderr.strip().splitlines()
    assert len(lines) == 1 and message in lines[0], res.stderr


def test_an_abort_from_another_thread_ends_a_running_map_without_resubmitting():
    """The evaluation maps its exact runs in a background thread; Ctrl-C reaches the main
    thread, which aborts the backend: the map must end at once with KeyboardInterrupt rather
    than take the killed workers for dead ones and resubmit their jobs."""
    import threading

    be = LocalBackend(2, retries=2)
    raised: list[BaseException] = []

    def mapping():
        try:
            be.map(time.sleep, [60.0] * 4)
        except BaseException as exc:  # noqa: BLE001 - what the thread ended with
            raised.append(exc)

    thread = threading.Thread(target=mapping)
    thread.start()
    time.sleep(2.0)  # the jobs are running
    t0 = time.perf_counter()
    be.abort()
    thread.join(timeout=20)
    assert not thread.is_alive() and time.perf_counter() - t0 < 15
    assert len(raised) == 1 and isinstance(raised[0], KeyboardInterrupt)
    assert be._pool is None  # no new pool was started for a retry
    be.close()


def test_each_scoring_setting_has_one_default_the_yamls():
    """ScoringConfig's defaults are run.yaml's ``eval`` values (one default per setting)."""
    from dataclasses import fields

    from omegaconf import OmegaConf

    shipped = OmegaConf.to_container(
        OmegaConf.load(Path(__file__).parents[1] / "experiments/conf/run.yaml").eval
    )
    assert isinstance(shipped, dict)
    plain = ScoringConfig()
    checked = 0
    for f in fields(ScoringConfig):
        # (ScoringConfig.planner holds the planner's knobs as keyword arguments, built from the
        # block by from_cfg below; eval.planner is one of those knobs, the planner's name)
        if f.name in shipped and f.name != "planner":
            want = shipped[f.name]
            got = getattr(plain, f.name)
            assert (list(got) if isinstance(got, tuple) else got) == want, f.name
            checked += 1
    assert checked >= 10
    assert ScoringConfig.from_cfg(shipped) == ScoringConfig(planner=ScoringConfig.from_cfg(shipped).planner)


def test_a_run_saved_before_a_setting_is_read_through_the_migration(tmp_path):
    """A run directory whose config.yaml predates a setting is read with the value it ran with,
    named in run_dir.LEGACY_SETTINGS; a config that has the key keeps it; a block the config lacks
    stays absent."""
    from omegaconf import OmegaConf

    from nca_qd.run_dir import LEGACY_SETTINGS, load_run_config
    from nca_qd.sim.free_flow import CONGESTED_MODEL_V3

    old, new, maze = tmp_path / "old", tmp_path / "new", tmp_path / "maze"
    for d, cfg in (
        (old, {"eval": {"exact": "selective"}}),
        (new, {"eval": {"screen_estimate": "free_flow", "screen_congested": [1.0, 2.0, 3.0]}}),
        (maze, {"domain": {"name": "maze"}}),
        (tmp_path / "maze2", {"domain": {"name": "maze"}, "eval": {"workers": None, "retries": 2}}),
    ):
        d.mkdir()
        OmegaConf.save(OmegaConf.create(cfg), d / "config.yaml")
    got = ScoringConfig.from_cfg(load_run_config(old).eval)
    assert got.screen_estimate == "scaled" and got.screen_congested == CONGESTED_MODEL_V3
    assert {"eval.screen_estimate", "eval.screen_congested"} <= set(LEGACY_SETTINGS)
    kept = ScoringConfig.from_cfg(load_run_config(new).eval)
    assert kept.screen_estimate == "free_flow" and kept.screen_congested == (1.0, 2.0, 3.0)
    assert "eval" not in load_run_config(maze)
    # a maze run's eval block (workers, retries) gets none of the multi-agent scorer's settings
    assert dict(load_run_config(tmp_path / "maze2").eval) == {"workers": None, "retries": 2}


def test_every_planner_setting_has_its_default_in_the_yamls_and_the_shipped_memos_still_load():
    """Each exact-planner knob is named in run.yaml (the search) and evaluate.yaml (the
    evaluation), so none falls back to a default in code; naming them must not change what a
    remembered result is keyed by: a scorer built from a shipped run's saved config has the
    fingerprint its memo was written under."""
    import json

    from omegaconf import OmegaConf

    from nca_qd.domains import make_domain
    from nca_qd.run_dir import load_run_config
    from nca_qd.sim.rhcr import PLANNER_KEYS

    conf = Path(__file__).parents[1] / "experiments/conf"
    assert set(PLANNER_KEYS) <= set(OmegaConf.load(conf / "run.yaml").eval)
    assert set(PLANNER_KEYS) <= set(OmegaConf.load(conf / "evaluate.yaml").exact)
    # (cma_mae_a1_s0 was fingerprinted before the repair's keep_aisles option, with it in config)
    runs = ("warehouse_even_qd/cma_mae_a5_s0", "warehouse_even_qd/cma_mae_a1_s0", "manufacturing_a5")
    for run in (*runs, "warehouse_uneven_a5"):
        run_dir = Path(__file__).parents[1] / "results" / run
        cfg = load_run_config(run_dir)
        saved = json.loads(str(np.load(run_dir / "eval_memo.npz")["fingerprint"]))
        scorer = make_domain(cfg.domain).make_evaluator(OmegaConf.merge(cfg, {"eval": {"workers": 0}}))
        try:
            assert json.loads(scorer.fingerprint) == saved, run
        finally:
            scorer.close()
