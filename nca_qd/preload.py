"""Import the whole ``nca_qd`` package at the start of a long run.

Why: many modules import others inside functions (optional dependencies, start-up time, import
cycles). A search, an evaluation or an agent's training runs for hours, and a commit made to the
working tree meanwhile is then read by the run's first call of such a function: a run that loaded
``nca_qd.run_dir`` at its start and ``nca_qd.run_pictures`` at its end mixes two commits, and a name
the new module imports from the old one fails. That killed a 90-minute maze search at its last
step (its archives were written; the pictures were not). Importing every module once, before the
run's first iteration, makes the run read its source at one moment: later edits to the tree cannot
reach it. It costs a few seconds of start-up (most of it the third-party modules a run imports
anyway), so only the long-running entry points call it.
"""

from __future__ import annotations

import importlib
import logging
import pkgutil

log = logging.getLogger(__name__)

_loaded: dict[str, list[str]] = {}


def preload(package: str = "nca_qd") -> list[str]:
    """Import every module of ``package`` (recursively) once per process; returns their names.

    A module whose import needs a third-party package that is not installed is skipped (its
    function reports that when called, as before); any other import error propagates, because a
    run must not start on a tree that cannot import.
    """
    if package in _loaded:
        return list(_loaded[package])
    root = importlib.import_module(package)
    names = [package]
    for info in pkgutil.walk_packages(root.__path__, prefix=f"{package}."):
        try:
            importlib.import_module(info.name)
        except ModuleNotFoundError as exc:
            if exc.name is None or exc.name == package or exc.name.startswith(f"{package}."):
                raise
            log.debug("preload: %s skipped (needs %s)", info.name, exc.name)
            continue
        names.append(info.name)
    _loaded[package] = names
    return list(names)
