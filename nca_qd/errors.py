"""User-facing errors.

Anything a user can cause (a bad map file, a wrong override, a resume directory of another
domain) raises :class:`NcaQdError`. Entry points catch it and print one line, exit status 2,
no traceback (see :func:`experiments.cli.main_guard`).
"""


class NcaQdError(Exception):
    """A problem with the user's input: the message is shown as one line."""


class MapFormatError(NcaQdError):
    """A map file that is not a valid layout (unknown tile, ragged rows, wrong sizes)."""


def require_bool(name: str, value: object) -> bool:
    """``value`` if it is a boolean, else :class:`NcaQdError` naming the setting: a YAML or
    command-line ``maybe`` or ``1`` would otherwise pass as true wherever code only tests it."""
    if not isinstance(value, bool):
        raise NcaQdError(f"{name} must be true or false, got {value!r}")
    return value
