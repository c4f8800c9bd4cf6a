"""experiments.cli.main_guard: what any entry point does with a user's mistake — one line on
stderr, exit 2, no traceback — for the mistakes no command checks by itself."""

from __future__ import annotations

import sys

import pytest
from omegaconf import OmegaConf

from experiments.cli import main_guard


def _run(body, monkeypatch, capsys):
    monkeypatch.setattr(sys, "argv", ["prog"])
    with pytest.raises(SystemExit) as exc:
        main_guard(body)()
    return exc.value.code, capsys.readouterr().err.strip().splitlines()


def test_a_required_setting_read_before_any_check_names_itself(monkeypatch, capsys):
    cfg = OmegaConf.create({"runs": "???", "nested": {"out": "???"}})
    code, err = _run(lambda argv: print(cfg.nested.out), monkeypatch, capsys)
    assert code == 2 and err == ["error: give nested.out=<value> (required; --help lists the settings)"]


def test_a_path_that_cannot_be_written_is_the_path_and_the_reason(tmp_path, monkeypatch, capsys):
    (tmp_path / "f").write_text("x")

    def body(argv):
        (tmp_path / "f" / "out").mkdir(parents=True)

    code, err = _run(body, monkeypatch, capsys)
    assert code == 2 and err == [f"error: {tmp_path / 'f' / 'out'}: Not a directory"]


def test_a_programming_error_is_not_dressed_as_a_user_error(monkeypatch, capsys):
    """Anything else keeps its traceback: a bug must not read as bad input."""

    def body(argv):
        raise ValueError("a bug")

    monkeypatch.setattr(sys, "argv", ["prog"])
    with pytest.raises(ValueError, match="a bug"):
        main_guard(body)()


def test_output_piped_into_a_reader_that_stops_ends_quietly(tmp_path, monkeypatch):
    """``python -m experiments.campaign … status=true | head -1``: the reader goes away, the
    command stops at its next line with exit 141 (a shell's SIGPIPE status), no traceback; a
    broken pipe that is not standard output stays an error with its traceback."""
    import subprocess

    plan = tmp_path / "plan.yaml"
    plan.write_text(
        f"root: {tmp_path / 'arms'}\narms:\n" + "".join(f"  a{i}: [seed={i}]\n" for i in range(5))
    )
    proc = subprocess.Popen(
        [sys.executable, "-m", "experiments.campaign", f"plan={plan}", "status=true"],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
    )
    proc.stdout.close()  # the reader is gone before the first line
    _, err = proc.communicate(timeout=120)
    assert proc.returncode == 141 and b"Traceback" not in err and b"BrokenPipe" not in err

    def body(argv):
        raise BrokenPipeError(32, "Broken pipe")  # e.g. a socket's, while stdout is a terminal

    import experiments.cli

    monkeypatch.setattr(experiments.cli, "_stdout_is_pipe", lambda: False)
    monkeypatch.setattr(sys, "argv", ["prog"])
    with pytest.raises(BrokenPipeError):
        main_guard(body)()


def test_a_value_with_an_equals_sign_gets_the_quoting_that_passes_it():
    """The paper's map files are named ``…_a=1.json``; Hydra's grammar stops at the second
    ``=``. The error names the override and its quoted form, which then composes."""
    from experiments.cli import compose_config
    from nca_qd.errors import NcaQdError

    with pytest.raises(NcaQdError) as exc:
        compose_config("simulate", ["layout=maps/x_a=1.json", "agents=10"])
    assert str(exc.value).endswith("""must be quoted: 'layout="maps/x_a=1.json"'""")
    assert compose_config("simulate", ['layout="maps/x_a=1.json"', "agents=10"]).layout == "maps/x_a=1.json"
    with pytest.raises(NcaQdError) as exc:  # another mistake: no hint
        compose_config("simulate", ["no_such_key=1"])
    assert "quoted" not in str(exc.value)


@pytest.mark.parametrize(
    "module, argv, name",
    [
        ("campaign", ["plan=warehouse_even_qd", "status=maybe"], "status"),
        ("export", ["human=maybe", "out=OUT"], "human"),
        ("export", ["run=x", "repair=1", "out=OUT"], "repair"),
        ("maze_transfer", ["pictures=maybe", "out=OUT"], "pictures"),
        ("train_agent", ["ship=maybe", "run_dir=OUT"], "ship"),
        ("run", ["domain=maze", "qd.progress=maybe", "run_dir=OUT"], "qd.progress"),
        ("run", ["domain=maze", "output.pictures=yes", "run_dir=OUT"], "output.pictures"),
    ],
)
def test_a_switch_that_is_not_true_or_false_is_refused_before_anything_runs(
    module, argv, name, tmp_path, monkeypatch, capsys
):
    """A YAML or command-line ``maybe`` (or ``1``) would pass as true wherever code only
    tests the value: each switch is refused by name, and the command leaves nothing behind."""
    import importlib

    main = importlib.import_module(f"experiments.{module}").main
    out = tmp_path / "out"
    monkeypatch.setattr(sys, "argv", ["prog", *(a.replace("OUT", str(out)) for a in argv)])
    with pytest.raises(SystemExit) as exc:
        main_guard(main)()
    err = capsys.readouterr().err.strip().splitlines()
    assert exc.value.code == 2
    assert err[-1].startswith(f"error: {name} must be true or false, got ")
    assert not out.exists() or not any(out.iterdir())


def test_the_benchmark_scripts_guard_says_the_same_in_one_line(tmp_path, capsys):
    """benchmarks.cli.guarded (the argparse scripts): a user error or a path that cannot be read
    is one line and 2, as main_guard gives; a script's own status passes through."""
    from benchmarks.cli import guarded
    from nca_qd.errors import NcaQdError

    def bad() -> None:
        raise NcaQdError("--band must be >= 1, got 0")

    missing = tmp_path / "none.json"
    assert guarded(bad) == 2
    assert guarded(lambda: missing.open().close()) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err == ["error: --band must be >= 1, got 0", f"error: {missing}: No such file or directory"]
    assert guarded(lambda: None) == 0 and guarded(lambda: 3) == 3
