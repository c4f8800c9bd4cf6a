"""Shared plumbing for entry points: config composition, one-line errors, exit codes.

Entry points compose their Hydra config with :func:`compose_config` (Hydra's compose API rather
than ``@hydra.main``, so that a wrong override becomes one line and exit status 2 instead of a
Hydra traceback) and wrap their body in :func:`main_guard`.
"""

from __future__ import annotations

import logging
import os
import signal
import stat
import sys
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

from omegaconf import DictConfig, OmegaConf
from omegaconf.errors import MissingMandatoryValue

from nca_qd.errors import NcaQdError

CONF_DIR = Path(__file__).resolve().parent / "conf"
EXIT_USAGE = 2
EXIT_INTERRUPTED = 130
EXIT_PIPE_CLOSED = 141  # as a shell reports a tool stopped by SIGPIPE

log = logging.getLogger("nca_qd")


def compose_config(config_name: str, overrides: Sequence[str]) -> DictConfig:
    """Compose ``experiments/conf/<config_name>.yaml`` with ``key=value`` overrides.

    Hydra and OmegaConf errors (unknown group option, wrong type, missing key) become
    :class:`NcaQdError` with Hydra's own one-line explanation.
    """
    from hydra import compose, initialize_config_dir
    from hydra.errors import HydraException
    from omegaconf.errors import OmegaConfBaseException

    try:
        with initialize_config_dir(config_dir=str(CONF_DIR), version_base="1.3"):
            cfg = compose(config_name=config_name, overrides=list(overrides))
        OmegaConf.resolve(cfg)
    except (HydraException, OmegaConfBaseException) as exc:
        hint = _quote_hint(overrides) if "mismatched input '='" in str(exc) else ""
        raise NcaQdError(f"bad configuration: {_explain(config_name, str(exc))}{hint}") from None
    return cfg


def _quote_hint(overrides: Sequence[str]) -> str:
    """Hydra's grammar stops at a second ``=`` (the paper's map files are named ``…_a=1.json``):
    name the override and the quoting that passes it."""
    for arg in overrides:
        key, _, value = arg.partition("=")
        if "=" in value and not value.startswith(("'", '"')):
            return f"; a value holding '=' must be quoted: '{key}=\"{value}\"'"
    return ""


def _explain(config_name: str, message: str) -> str:
    """Hydra's error in one line: its first line, the options it lists (an unknown domain or
    algorithm), or for an unknown key the keys of the config nearest to it."""
    import difflib
    import re

    lines = [ln.strip() for ln in message.strip().splitlines() if ln.strip()]
    if not lines:
        return "invalid configuration"
    first = lines[0]
    if "Available options" in message:
        opts = []
        for ln in lines[lines.index(next(x for x in lines if x.startswith("Available options"))) + 1 :]:
            if ln.startswith("Config search path"):
                break
            opts.append(ln)
        return f"{first} (known: {', '.join(opts)})"
    unknown = re.match(r"Could not override '([^']+)'", first)
    if unknown:
        keys = _config_keys(config_name)
        near = difflib.get_close_matches(unknown.group(1), keys, n=3, cutoff=0.6)
        hint = f"; did you mean {' or '.join(near)}?" if near else ""
        return f"no setting {unknown.group(1)!r} in {config_name}.yaml{hint}"
    return first


def _config_keys(config_name: str) -> list[str]:
    """Every dotted key of the composed default config (for suggestions)."""
    from hydra import compose, initialize_config_dir

    with initialize_config_dir(config_dir=str(CONF_DIR), version_base="1.3"):
        cfg = OmegaConf.to_container(compose(config_name=config_name), resolve=False)

    def walk(node, prefix: str):
        if isinstance(node, dict):
            for k, v in node.items():
                yield from walk(v, f"{prefix}{k}.")
        yield prefix.rstrip(".")

    return [k for k in walk(cfg, "") if k]


def check_writable(path, what: str) -> None:
    """Refuse, before any work, an output file that could not be written: its folder missing
    or read-only, or the path a folder (the result would otherwise be lost after the work)."""
    import os

    target = Path(str(path))
    if target.is_dir():
        raise NcaQdError(f"{what}={target}: is a folder, not a file")
    parent = target.parent if str(target.parent) else Path(".")
    if not parent.is_dir():
        raise NcaQdError(f"{what}={target}: folder {parent} does not exist")
    if not os.access(parent, os.W_OK):
        raise NcaQdError(f"{what}={target}: folder {parent} is not writable")


def print_help(module_name: str) -> None:
    """What ``--help`` shows: the command's docstring, then its settings file with comments."""
    module = sys.modules.get(module_name)
    doc = (module.__doc__ or "").strip() if module is not None else ""
    name = module_name.rsplit(".", 1)[-1]
    print(doc or f"python -m experiments.{name} key=value ...")
    conf = CONF_DIR / f"{name}.yaml"
    if conf.is_file():
        print(f"\nSettings (key=value on the command line; defaults from experiments/conf/{name}.yaml):\n")
        print(conf.read_text().rstrip())


def merge_overrides(cfg: DictConfig, overrides: Sequence[str]) -> DictConfig:
    """``cfg`` with ``key=value`` overrides merged in (a resumed run's saved config); a malformed
    override is one clear error."""
    try:
        return OmegaConf.merge(cfg, OmegaConf.from_dotlist(list(overrides)))
    except Exception as exc:  # OmegaConf's parse errors for malformed overrides
        raise NcaQdError(f"bad override: {str(exc).splitlines()[0]}") from None


def take_domain(argv: list[str]) -> tuple[list[str], str | None]:
    """Pull ``domain=...`` out of the overrides.

    Hydra reads ``domain=`` as a choice of the config *group* ``conf/domain/`` (used by
    run.yaml) and refuses it for configs where ``domain`` is a plain string (simulate.yaml)
    or absent (evaluate.yaml); so the caller uses the value itself.
    """
    rest, domain = [], None
    for arg in argv:
        key, sep, value = arg.partition("=")
        if sep and key.lstrip("+~") == "domain":
            domain = value
        else:
            rest.append(arg)
    return rest, domain


def size_pair(value: Any, what: str) -> tuple[int, int]:
    """A command line's ``[rows, cols]`` (``tile=[101,102]``, ``crop=[70,140]``) as two positive
    integers; anything else is a usage error naming ``what``."""
    vals = list(value) if hasattr(value, "__len__") and not isinstance(value, str) else []
    if len(vals) != 2 or not all(isinstance(v, int) and not isinstance(v, bool) and v > 0 for v in vals):
        raise NcaQdError(f"{what} must be [rows, cols] of positive integers, got {value!r}")
    return int(vals[0]), int(vals[1])


def _raise_interrupt(signum, frame) -> None:
    raise KeyboardInterrupt


RESUME_HINT = "the last checkpoint is intact; resume with resume=<run dir>"


def path_error(exc: OSError) -> str:
    """``<path>: <reason>`` for a file-system error (both paths of a failed rename or copy)."""
    paths = [str(p) for p in (exc.filename, exc.filename2) if p is not None]
    reason = exc.strerror or str(exc)
    return f"{' -> '.join(paths)}: {reason}" if paths else reason


def _stdout_is_pipe() -> bool:
    try:
        return stat.S_ISFIFO(os.fstat(sys.stdout.fileno()).st_mode)
    except (OSError, ValueError):
        return False


def main_guard(body: Callable[[list[str]], int | None], on_interrupt: str = "") -> Callable[[], None]:
    """Run ``body(argv)``; user errors (a map too large for memory among them: the stages
    refuse it from their estimates, nca_qd.memory, and an allocation that fails all the same
    is caught here) print one line to stderr and exit 2, Ctrl-C (or SIGTERM) exits 130 with
    ``on_interrupt`` (what was kept, how to go on) in its line."""

    def wrapped() -> None:
        logging.basicConfig(
            level=logging.WARNING, format="%(asctime)s %(name)s: %(message)s", datefmt="%H:%M:%S"
        )
        logging.getLogger("nca_qd").setLevel(logging.INFO)
        # SIGTERM (a cluster scheduler's or a session's end, `kill`) stops a run as Ctrl-C
        # does: the run writes its checkpoint before it exits.
        signal.signal(signal.SIGTERM, _raise_interrupt)
        if any(a in ("-h", "--help", "help") for a in sys.argv[1:]):
            print_help(body.__module__)
            sys.exit(0)
        try:
            code = body(sys.argv[1:])
        except NcaQdError as exc:
            print(f"error: {exc}", file=sys.stderr)
            sys.exit(EXIT_USAGE)
        except MemoryError as exc:  # a map or an agent count beyond this machine: the input's size
            print(
                f"error: out of memory ({exc or 'allocation failed'}): ask for a smaller map or fewer agents",
                file=sys.stderr,
            )
            sys.exit(EXIT_USAGE)
        except MissingMandatoryValue as exc:  # a setting the YAML leaves ??? for the user
            key = exc.full_key
            print(f"error: give {key}=<value> (required; --help lists the settings)", file=sys.stderr)
            sys.exit(EXIT_USAGE)
        except (FileNotFoundError, NotADirectoryError, IsADirectoryError, PermissionError) as exc:
            # a path given on the command line that cannot be read or written (an output folder
            # under a missing or read-only parent): the path and the reason, not a traceback
            print(f"error: {path_error(exc)}", file=sys.stderr)
            sys.exit(EXIT_USAGE)
        except KeyboardInterrupt:
            print(f"interrupted{': ' + on_interrupt if on_interrupt else ''}", file=sys.stderr)
            sys.exit(EXIT_INTERRUPTED)
        except BrokenPipeError:
            if not _stdout_is_pipe():
                raise
            # the reader of the output went away (`... status=true | head`): stop quietly, as a
            # shell tool does, and keep Python's exit-time flush from failing again
            os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
            sys.exit(EXIT_PIPE_CLOSED)
        sys.exit(code or 0)

    return wrapped
