"""What the benchmark scripts share on the command line: a user error (an ``NcaQdError``, a path
that cannot be read or written) is one line on stderr and exit status 2, as in the commands
under ``experiments`` (:func:`experiments.cli.main_guard`, whose Hydra help and signal handling
an ``argparse`` script does not need)."""

from __future__ import annotations

import sys
from collections.abc import Callable

from experiments.cli import EXIT_USAGE, path_error
from nca_qd.errors import NcaQdError


def guarded(work: Callable[[], int | None]) -> int:
    """``work()``'s exit status (None: 0), or 2 after one ``error: ...`` line for a user error."""
    try:
        return work() or 0
    except NcaQdError as exc:
        print(f"error: {exc}", file=sys.stderr)
    except OSError as exc:
        print(f"error: {path_error(exc)}", file=sys.stderr)
    return EXIT_USAGE
