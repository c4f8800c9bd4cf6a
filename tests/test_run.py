"""End to end: a short maze run writes every output; resume continues to the same end; bad
input gets one line and a non-zero exit."""

import csv
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from conftest import TINY_MAZE as TINY

from experiments.cli import compose_config, main_guard
from nca_qd.experiment import Experiment

REPO = Path(__file__).resolve().parents[1]
OUTPUTS = [
    "config.yaml",
    "metrics.csv",
    "checkpoint.npz",
    "archive_result.npz",
    "archive_opt.npz",
    "elites.npz",
    "archive_result.png",
    "archive_opt.png",
    "curves.png",
    "best_train.png",
    "best_eval.png",
]


def _cfg(*extra):
    return compose_config("run", TINY + list(extra))


def _metrics(run_dir):
    with open(run_dir / "metrics.csv") as fh:
        return list(csv.DictReader(fh))


def test_short_maze_run_writes_every_output(full_run):
    run_dir, exp, state = full_run
    for name in OUTPUTS:
        assert (run_dir / name).is_file(), name
    rows = _metrics(run_dir)
    assert [int(r["iteration"]) for r in rows] == list(range(1, 6))
    assert int(rows[-1]["evaluations"]) == 40
    for col in ("qd_score", "coverage", "best_objective", "wall_seconds"):
        assert col in rows[-1]
    archive = np.load(run_dir / "archive_result.npz")
    occupied = np.isfinite(archive["objective"])
    assert occupied.all() and 0 < occupied.size <= 40  # elites only, not the 41,472-cell grid
    assert archive["genotypes"].shape == (occupied.size, 1730)
    assert archive["cells"].shape == (occupied.size,) and archive["grid_cells"].tolist() == [256, 162]
    assert float(rows[-1]["coverage"]) == pytest.approx(occupied.size / (256 * 162))


def test_exact_resume_continues_and_ends_where_an_uninterrupted_run_ends(full_run, tmp_path):
    """checkpoint.exact=true: the resumed run replays the uninterrupted one bit for bit."""
    run_dir, _, reference = full_run
    # first leg: stop after 24 evaluations (3 iterations), then resume to 40
    part = tmp_path / "resumed"
    Experiment(_cfg("qd.n_evals=24", "output.pictures=false", "checkpoint.exact=true"), part).run()
    assert [int(r["iteration"]) for r in _metrics(part)] == [1, 2, 3]
    exp = Experiment(_cfg("qd.n_evals=40", "output.pictures=false", "checkpoint.exact=true"), part)
    state = exp.run(resume=True)
    assert [int(r["iteration"]) for r in _metrics(part)] == [1, 2, 3, 4, 5]
    np.testing.assert_array_equal(
        np.asarray(state.res_archive.fitnesses), np.asarray(reference.res_archive.fitnesses)
    )
    np.testing.assert_array_equal(
        np.asarray(state.opt_archive.thresholds), np.asarray(reference.opt_archive.thresholds)
    )


def test_a_run_in_progress_is_read_from_its_checkpoint(full_run, tmp_path):
    """Before archive_*.npz exist (a long run still going), load_archive reads the checkpoint's
    archive: the same arrays the finished run writes; a damaged checkpoint is one clear error."""
    import shutil

    from nca_qd.errors import NcaQdError
    from nca_qd.experiment import load_archive

    run_dir, _, _ = full_run
    live = tmp_path / "live"
    live.mkdir()
    for name in ("config.yaml", "checkpoint.npz"):
        shutil.copy(run_dir / name, live / name)
    for which in ("result", "opt"):
        got, want = load_archive(live, which), load_archive(run_dir, which)
        assert sorted(got) == sorted(want)
        occupied = np.isfinite(want["objective"])
        for k in ("objective", "measures", "centroids", "cells"):
            np.testing.assert_array_equal(got[k], want[k], err_msg=f"{which}/{k}")
        cells = np.flatnonzero(occupied)
        # Result elites are exact; optimisation elites that are only restart points are stored
        # at int8 per row in the checkpoint (error <= 1/510 of the row's range).
        a, b = got["genotypes"][cells], want["genotypes"][cells]
        if which == "result":
            np.testing.assert_array_equal(a, b)
        else:
            span = b.max(axis=1) - b.min(axis=1)
            assert np.all(np.abs(a - b).max(axis=1) <= span / 510 * 1.001 + 1e-6)
    (live / "checkpoint.npz").write_bytes(b"not a checkpoint")
    with pytest.raises(NcaQdError, match="not a readable checkpoint"):
        load_archive(live)
    (live / "checkpoint.npz").unlink()
    with pytest.raises(NcaQdError, match="no checkpoint.npz"):
        load_archive(live)


def _cli(*args, timeout=300):
    env = {**os.environ, "JAX_PLATFORMS": "cpu"}
    return subprocess.run(
        [sys.executable, "-m", "experiments.run", *args],
        cwd=REPO,
        capture_output=True,
        text=True,
        timeout=timeout,
        env=env,
    )


def _cli_here(args, capsys, monkeypatch):
    """experiments.run as its console entry runs it, in this process: (exit status, stderr)."""
    from experiments.run import main

    monkeypatch.setattr(sys, "argv", ["experiments.run", *args])
    previous = signal.getsignal(signal.SIGTERM)  # main_guard installs its own
    try:
        with pytest.raises(SystemExit) as exc:
            main_guard(main)()
    finally:
        signal.signal(signal.SIGTERM, previous)
    return exc.value.code, capsys.readouterr().err


@pytest.mark.parametrize(
    "args,message",
    [
        (["domain=nowhere"], "(known: manufacturing, maze, maze_entropy, warehouse_even, warehouse_uneven)"),
        (["algo=simulated_annealing"], "(known: cma_es, cma_mae, dsage, map_elites)"),
        (["sed=3"], "no setting 'sed' in run.yaml; did you mean seed?"),
        (
            ["domain=warehouse_even", "domain.size.train=[3,3]"],
            "domain.size.train=[3, 3]: no valid layout exists (240 tiles of '@' required, room for 9)",
        ),
        (["qd.n_eval=150"], "did you mean qd.n_evals"),
        (["qd.n_evals=abc"], "qd.n_evals must be a positive integer"),
        (["qd.n_evals=-5"], "qd.n_evals must be a positive integer"),
        (["domain.size.train=[0,16]"], "domain.size.train must be two integers"),
        (["resume=/nonexistent/run"], "does not exist"),
        (["checkpoint.restart_dtype=int4"], "checkpoint restart_dtype must be int8, float16 or float32"),
        (["checkpoint.exact=maybe"], "checkpoint exact must be true or false"),
        (["allow_simulator_change=maybe"], "allow_simulator_change must be true or false"),
        (["snapshot.exact_elites=-1"], "checkpoint exact_elites must be a non-negative integer"),
        (["snapshot.enabled=sometimes"], "snapshot.enabled must be true, false or auto"),
        (["leg_seconds=0"], "leg_seconds must be a positive number of seconds or null"),
        (["qd.checkpoint_seconds=0"], "qd.checkpoint_seconds must be a positive number"),
        (["qd.checkpoint_every=0"], "qd.checkpoint_every must be a positive integer"),
        (["leg_seconds=soon"], "leg_seconds must be a positive number of seconds or null"),
        (["algo=map_elites", "algo.initial_sigma=abc"], "algo.initial_sigma must be a positive number"),
        (["algo=map_elites", "algo.n_initial=-5"], "algo.n_initial must be an integer >= 0, got -5"),
        (["algo=map_elites", "algo.line_sigma=-0.1"], "algo.line_sigma must be a number >= 0"),
        (["algo=map_elites", "algo.archive=soft"], "algo.archive must be one of auto, elitist, threshold"),
    ],
)
def test_bad_input_gets_one_line_and_exit_2(args, message, capsys, monkeypatch):
    code, err = _cli_here(args, capsys, monkeypatch)
    assert code == 2, err
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: ") and message in lines[0], err
    assert "Traceback" not in err


@pytest.mark.parametrize(
    "command, flag, expect",
    [
        ("run", "--help", "n_evals"),
        ("evaluate", "-h", "select"),
        ("repair", "--help", "tie_break"),
        ("simulate", "--help", "agents"),
        ("dynamics", "-h", "shift_tol"),
    ],
)
def test_help_prints_the_commands_purpose_and_settings(command, flag, expect, capsys, monkeypatch):
    """--help / -h: the command's docstring and its settings file, exit 0 (Hydra's parser used to
    answer 'LexerNoViableAltException')."""
    import importlib

    module = importlib.import_module(f"experiments.{command}")
    monkeypatch.setattr(sys, "argv", [f"experiments.{command}", flag])
    previous = signal.getsignal(signal.SIGTERM)
    try:
        with pytest.raises(SystemExit) as exc:
            main_guard(module.main)()
    finally:
        signal.signal(signal.SIGTERM, previous)
    out, err = capsys.readouterr()
    assert exc.value.code == 0 and not err
    assert f"experiments/conf/{command}.yaml" in out and expect in out
    assert out.splitlines()[0] == module.__doc__.strip().splitlines()[0]


def test_a_real_process_exits_2_with_one_line():
    """The same guard as above, seen from outside: exit status and stderr of a real process."""
    out = _cli("qd.n_evals=abc")
    assert out.returncode == 2, out.stderr
    lines = out.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: qd.n_evals must be a positive integer")


def test_resume_of_another_domain_is_refused(full_run, capsys, monkeypatch):
    run_dir, _, _ = full_run
    code, err = _cli_here([f"resume={run_dir}", "domain=warehouse_even"], capsys, monkeypatch)
    assert code == 2 and "holds a domain 'maze' run" in err


def test_ctrl_c_leaves_a_resumable_checkpoint(tmp_path):
    run_dir = tmp_path / "interrupted"
    args = TINY + ["qd.n_evals=4000", f"run_dir={run_dir}"]
    # A child inherits SIGINT *ignored* (as in a pytest-xdist worker or a background job) but
    # not a handler: with one installed here while it starts, Ctrl-C has its default action
    # in the child.
    old = signal.signal(signal.SIGINT, signal.default_int_handler)
    try:
        proc = subprocess.Popen(
            [sys.executable, "-m", "experiments.run", *args],
            cwd=REPO,
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
            env={**os.environ, "JAX_PLATFORMS": "cpu"},
        )
    finally:
        signal.signal(signal.SIGINT, old)
    deadline = time.time() + 240
    while time.time() < deadline and not (run_dir / "checkpoint.npz").exists():
        time.sleep(0.5)
    assert (run_dir / "checkpoint.npz").exists(), "no checkpoint appeared"
    time.sleep(1.0)
    proc.send_signal(signal.SIGINT)
    _, err = proc.communicate(timeout=120)
    assert proc.returncode == 130, err
    assert "resume with resume=" in err and "Traceback" not in err
    done = len(_metrics(run_dir))
    from experiments.run import main

    assert main([f"resume={run_dir}", "qd.n_evals=" + str(8 * (done + 2)), "output.pictures=false"]) == 0
    rows = _metrics(run_dir)
    assert [int(r["iteration"]) for r in rows] == list(range(1, done + 3))


def test_a_leg_ends_before_an_iteration_it_cannot_finish_and_resume_goes_on(tmp_path):
    """leg_seconds: without an iteration to judge by, a leg runs one; once it knows an
    iteration's length it checkpoints and exits 75 before one that would end too late, losing
    nothing; the setting is not saved, so a plain resume runs to the end."""
    from experiments.run import EXIT_LEG_ENDED, main

    run_dir = tmp_path / "legs"
    quick = ["output.pictures=false", "qd.checkpoint_every=10"]
    assert main(TINY + quick + [f"run_dir={run_dir}", "leg_seconds=0.001"]) == EXIT_LEG_ENDED
    assert [int(r["iteration"]) for r in _metrics(run_dir)] == [1]  # one, then no room for another
    assert (run_dir / "checkpoint.npz").is_file()  # saved although checkpoint_every is 10
    assert not (run_dir / "archive_result.npz").exists()  # a leg's end is not the search's
    assert "leg_seconds" not in (run_dir / "config.yaml").read_text()
    # Judged by the recorded iteration, the next leg starts none at all.
    assert main([f"resume={run_dir}", "leg_seconds=0.001"]) == EXIT_LEG_ENDED
    assert [int(r["iteration"]) for r in _metrics(run_dir)] == [1]
    assert main([f"resume={run_dir}", "leg_seconds=3600"]) == 0
    assert [int(r["iteration"]) for r in _metrics(run_dir)] == list(range(1, 6))
    assert (run_dir / "archive_result.npz").is_file()


def test_a_leg_judges_its_iterations_by_its_own_once_it_has_run_one(tmp_path, monkeypatch):
    """A run resumed on a faster machine (recorded iterations of 100 s, here ~0.1 s) runs on
    to the end of its leg: once the leg has run an iteration, the recorded ones no longer
    count. The leg's clock is faked: each look at it advances it by one second."""
    import types

    from experiments.run import EXIT_LEG_ENDED, main

    run_dir = tmp_path / "moved"
    quick = ["output.pictures=false", "qd.checkpoint_every=1"]
    assert main(TINY + quick + [f"run_dir={run_dir}", "qd.n_evals=16"]) == 0
    rows = _metrics(run_dir)
    assert [int(r["iteration"]) for r in rows] == [1, 2]
    for row in rows:  # as if recorded on a machine 1000 times slower
        row["step_seconds"] = "100"
    with open(run_dir / "metrics.csv", "w", newline="") as fh:
        writer = csv.DictWriter(fh, fieldnames=list(rows[0]))
        writer.writeheader()
        writer.writerows(rows)

    ticks = iter(range(10**6))
    clock = types.SimpleNamespace(monotonic=lambda: float(next(ticks)), perf_counter=time.perf_counter)
    monkeypatch.setattr("nca_qd.experiment.time", clock)
    # 1 s in + 100 s recorded fits in 102 s: the leg runs one; judged by the recorded 100 s
    # it would stop at the next look (3 + 100 > 102), judged by its own it goes on to the end.
    assert main([f"resume={run_dir}", "qd.n_evals=48", "leg_seconds=102"]) == 0
    assert [int(r["iteration"]) for r in _metrics(run_dir)] == list(range(1, 7))
    # A leg that has not run one is still judged by the recorded iterations: it starts none.
    ticks = iter(range(10**6))
    assert main([f"resume={run_dir}", "qd.n_evals=64", "leg_seconds=50"]) == EXIT_LEG_ENDED
    assert len(_metrics(run_dir)) == 6


def test_wall_seconds_counts_the_checkpoints_between_steps(tmp_path, monkeypatch):
    """A search's wall clock is more than its steps: each checkpoint (here made 0.3 s slower)
    shows in the next row's wall_seconds, so a run whose steps are fast (a GPU) reports its
    real cost."""
    slow = 0.3
    save = Experiment.save_checkpoint

    def slow_save(self, state, wall):
        time.sleep(slow)
        save(self, state, wall)

    monkeypatch.setattr(Experiment, "save_checkpoint", slow_save)
    run_dir = tmp_path / "wall"
    Experiment(_cfg("qd.n_evals=24", "output.pictures=false", "qd.checkpoint_every=1"), run_dir).run()
    rows = _metrics(run_dir)
    wall = [float(r["wall_seconds"]) for r in rows]
    step = [float(r["step_seconds"]) for r in rows]
    assert len(rows) == 3 and wall[0] >= step[0]
    for i in (1, 2):  # the checkpoint after row i-1 belongs to row i
        assert wall[i] - wall[i - 1] >= step[i] + slow


@pytest.mark.parametrize(
    "seconds,every,saved",
    [(100, None, [3, 6]), (60, 5, [2, 4, 5, 6]), (None, None, [6])],
    ids=["by-time", "by-time-and-count", "only-at-the-end"],
)
def test_checkpoints_follow_the_clock_and_the_count(tmp_path, monkeypatch, seconds, every, saved):
    """qd.checkpoint_seconds: a checkpoint after the first iteration that ends that long after
    the last one; qd.checkpoint_every adds one every so many iterations; the end always has one.
    The clock is faked: each step takes 40 s of it."""
    import types

    from nca_qd.qd.loop import QDLoop

    now = [0.0]
    monkeypatch.setattr(
        "nca_qd.experiment.time", types.SimpleNamespace(monotonic=time.monotonic, perf_counter=lambda: now[0])
    )
    step = QDLoop.step

    def slow_step(self, state):
        out = step(self, state)
        now[0] += 40.0
        return out

    monkeypatch.setattr(QDLoop, "step", slow_step)
    iterations = []
    save = Experiment.save_checkpoint
    monkeypatch.setattr(
        Experiment,
        "save_checkpoint",
        lambda self, st, wall: (iterations.append(int(st.iteration)), save(self, st, wall)),
    )
    cfg = _cfg(
        "qd.n_evals=48",
        "output.pictures=false",
        f"qd.checkpoint_seconds={'null' if seconds is None else seconds}",
        f"qd.checkpoint_every={'null' if every is None else every}",
    )
    Experiment(cfg, tmp_path / "clock").run()
    assert len(_metrics(tmp_path / "clock")) == 6
    assert iterations == saved


@pytest.mark.parametrize("snapshot", [None, b"PK\x03\x04 cut short"], ids=["missing", "truncated"])
def test_a_run_directory_without_a_usable_snapshot_is_one_line_and_nothing_changes(
    full_run, tmp_path, snapshot, capsys, monkeypatch
):
    """What a fresh clone of results/<run>/ may hold when a leg's snapshot was never committed
    or arrived cut short: resume says so in one line, exits 2, and rewrites none of the files."""
    import shutil

    run_dir = tmp_path / "results" / "run"
    run_dir.mkdir(parents=True)
    for name in ("config.yaml", "metrics.csv"):
        shutil.copy(full_run[0] / name, run_dir / name)
    if snapshot is not None:
        (run_dir / "snapshot.npz").write_bytes(snapshot)
    before = {f.name: f.read_bytes() for f in run_dir.iterdir()}
    code, err = _cli_here([f"resume={run_dir}"], capsys, monkeypatch)
    lines = err.strip().splitlines()
    assert code == 2 and len(lines) == 1 and lines[0].startswith("error: "), err
    expected = "neither checkpoint.npz nor snapshot.npz" if snapshot is None else "not a readable checkpoint"
    assert expected in lines[0]
    assert {f.name: f.read_bytes() for f in run_dir.iterdir()} == before


def test_sigterm_stops_like_ctrl_c(capsys):
    """SIGTERM (a scheduler's or a session's end) becomes the KeyboardInterrupt that makes a run
    write its checkpoint (the test above) and exit 130 with the resume hint."""
    from experiments.cli import RESUME_HINT, main_guard

    reached = []

    def body(argv):
        try:
            os.kill(os.getpid(), signal.SIGTERM)
            time.sleep(10)
        except KeyboardInterrupt:
            reached.append("checkpoint here")
            raise
        return 0

    old = signal.getsignal(signal.SIGTERM)
    try:
        with pytest.raises(SystemExit) as exc:
            main_guard(body, RESUME_HINT)()
    finally:
        signal.signal(signal.SIGTERM, old)
    assert exc.value.code == 130 and reached == ["checkpoint here"]
    assert "resume with resume=" in capsys.readouterr().err


def test_render_draws_archive_elites(full_run, tmp_path):
    from experiments.render import render_elites
    from nca_qd.errors import NcaQdError

    run_dir, _, _ = full_run
    out = tmp_path / "elites.png"
    render_elites(out, run_dir, 2, "eval")
    assert out.stat().st_size > 1000 and out.read_bytes()[:4] == b"\x89PNG"
    with pytest.raises(NcaQdError, match="no elite in cell"):
        render_elites(tmp_path / "x.png", run_dir, [256 * 162 - 1, 10**9], "train")


@pytest.mark.parametrize("algo", ["map_elites", "cma_es"])
def test_baselines_run_end_to_end(algo, tmp_path):
    state = Experiment(_cfg(f"algo={algo}", "qd.n_evals=16", "output.pictures=false"), tmp_path / algo).run()
    assert int(state.evaluations) == 16
    assert bool(np.isfinite(np.asarray(state.res_archive.fitnesses)).any())
    # the baselines use a plain archive: thresholds equal the elites' objectives
    occupied = np.asarray(state.opt_archive.occupied)
    np.testing.assert_array_equal(
        np.asarray(state.opt_archive.thresholds)[occupied],
        np.asarray(state.opt_archive.fitnesses[:, 0])[occupied],
    )


def test_render_redraws_a_runs_pictures_from_its_checkpoint_alone(full_run, tmp_path, monkeypatch, capsys):
    """pictures=true draws what the run drew, from config, metrics and checkpoint only (a run in
    progress, or a snapshot on a fresh clone): same files, identical archive and layout pictures."""
    import shutil

    from experiments import render as render_cli

    run_dir, _, _ = full_run
    partial = tmp_path / "partial"
    partial.mkdir()
    for name in ("config.yaml", "metrics.csv", "checkpoint.npz"):
        shutil.copy(run_dir / name, partial / name)
    out = tmp_path / "pictures"
    monkeypatch.setattr(sys, "argv", ["render", f"run={partial}", "pictures=true", f"out={out}"])
    with pytest.raises(SystemExit) as exc:
        main_guard(render_cli.main)()
    assert exc.value.code == 0
    pictures = sorted(n for n in OUTPUTS if n.endswith(".png"))
    assert sorted(p.name for p in out.iterdir()) == pictures
    assert capsys.readouterr().out.split() == [
        str(out / n)
        for n in ("archive_result.png", "archive_opt.png", "curves.png", "best_train.png", "best_eval.png")
    ]
    for name in ("archive_result.png", "archive_opt.png", "best_train.png", "best_eval.png"):
        assert (out / name).read_bytes() == (run_dir / name).read_bytes(), name


@pytest.mark.parametrize(
    "where, enabled, expected",
    [
        ("results/leg", "auto", True),
        ("runs/leg", "auto", False),
        ("results/leg", "false", False),
        ("runs/leg", "true", True),
    ],
)
def test_a_run_kept_under_results_writes_its_portable_snapshot_by_default(tmp_path, where, enabled, expected):
    """snapshot.enabled=auto (the default): a run directory under results/ (meant for git) gets
    the portable snapshot a fresh clone resumes from; elsewhere only when asked."""
    exp = Experiment(_cfg(f"snapshot.enabled={enabled}"), tmp_path / where)
    assert (exp.snapshot_policy is not None) == expected


def test_a_run_without_its_archive_says_whether_it_ran(tmp_path):
    """No archive, checkpoint or snapshot: a run before its first iteration is told so; a run
    whose metrics record iterations (a shipped study that kept only config, metrics and
    pictures) is told its archive was not kept and how to rebuild it."""
    from nca_qd.errors import NcaQdError
    from nca_qd.run_dir import load_archive

    (tmp_path / "config.yaml").write_text("seed: 0\n")
    (tmp_path / "metrics.csv").write_text("iteration,evaluations,qd_score,coverage\n")
    with pytest.raises(NcaQdError, match=r"has the run finished an iteration yet\?"):
        load_archive(tmp_path)
    with (tmp_path / "metrics.csv").open("a") as fh:
        fh.write("1,150,10,0.1\n2,300,20,0.2\n")
    with pytest.raises(NcaQdError, match="records 2 iterations, so its archive was not kept here: re-run it"):
        load_archive(tmp_path)


def test_the_elites_record_ships_the_archives_figures_and_its_best_generators(
    full_run, tmp_path, capsys, monkeypatch
):
    """A run shipped with config, metrics and elites.npz only (the maze table's): the result
    archive reads back cell for cell from it (every elite's objective and measures), its kept
    generators grow the same layouts, a generator it did not keep is one clear line, and its
    pictures are drawn from it."""
    import shutil

    from experiments import render as render_cli
    from nca_qd.api import load_generator
    from nca_qd.errors import NcaQdError
    from nca_qd.qd import archive_io
    from nca_qd.run_dir import load_archive

    run_dir, _, _ = full_run
    whole = load_archive(run_dir)
    occupied = np.flatnonzero(np.isfinite(whole["objective"]))
    # the run's own record: every elite (fewer than kept_elites), each generator exact
    own = load_archive(_shipped(run_dir, tmp_path / "own", "elites.npz"))
    np.testing.assert_array_equal(own["objective"], whole["objective"])
    np.testing.assert_array_equal(
        np.asarray(own["genotypes"][occupied]), np.asarray(whole["genotypes"][occupied])
    )
    # a record keeping two elites, as a large archive's would keep 64 of thousands
    best = int(np.argmax(whole["objective"]))
    rest = [int(c) for c in occupied if c != best]
    assert len(rest) >= 2
    other = rest[0]
    kept_dir = tmp_path / "kept"
    kept_dir.mkdir()
    for name in ("config.yaml", "metrics.csv"):
        shutil.copy(run_dir / name, kept_dir / name)
    with np.load(run_dir / "archive_result.npz") as z:
        elites = {k: z[k] for k in z.files}
    archive_io.save_elites_record(
        kept_dir / "elites.npz", elites, [best, rest[-1]], [256, 162], [[0, 1], [0, 1]]
    )
    record = load_archive(kept_dir)
    np.testing.assert_array_equal(record["objective"], whole["objective"])
    np.testing.assert_array_equal(record["measures"], whole["measures"])
    assert _qd_score(record) == pytest.approx(float(_metrics(run_dir)[-1]["qd_score"]), abs=1e-3)
    np.testing.assert_array_equal(load_generator(kept_dir).layout(), load_generator(run_dir).layout())
    with pytest.raises(
        NcaQdError, match=f"keeps the generators of 2 of {occupied.size} elites, not of cell {other}"
    ):
        load_generator(kept_dir, other)
    with pytest.raises(NcaQdError, match="hold no elite"):
        archive_io.save_elites_record(
            tmp_path / "x.npz",
            elites,
            [int(np.flatnonzero(~np.isfinite(whole["objective"]))[0])],
            [256, 162],
            [[0, 1], [0, 1]],
        )
    # pictures from the record: the result archive and the elites it kept (n_best=2 here)
    monkeypatch.setattr(
        sys, "argv", ["render", f"run={_shipped(run_dir, tmp_path / 'pics', 'elites.npz')}", "pictures=true"]
    )
    with pytest.raises(SystemExit) as exc:
        main_guard(render_cli.main)()
    assert exc.value.code == 0
    drawn = sorted(Path(p).name for p in capsys.readouterr().out.split())
    assert drawn == ["archive_result.png", "best_eval.png", "best_train.png", "curves.png"]
    assert (tmp_path / "pics" / "best_train.png").read_bytes() == (run_dir / "best_train.png").read_bytes()


def _shipped(run_dir, to, *names):
    """A copy of what a shipped run keeps: config, metrics and ``names``."""
    import shutil

    to.mkdir()
    for name in ("config.yaml", "metrics.csv", *names):
        shutil.copy(run_dir / name, to / name)
    return to


def _qd_score(archive):
    """QD-score as the paper counts it for the maze (its objective is 0/1: offset 0)."""
    objective = np.asarray(archive["objective"])
    return float(objective[np.isfinite(objective)].sum())


def test_kept_elites_is_checked(tmp_path):
    from nca_qd.errors import NcaQdError

    with pytest.raises(NcaQdError, match="output.kept_elites must be an integer >= 0, got -1"):
        Experiment(_cfg("output.kept_elites=-1"), tmp_path / "run")
