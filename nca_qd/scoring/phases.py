"""Scoring a generator by more than one phase of its NCA (``eval.phases``; 1, the paper's
protocol, by default).

Why: most generators of the shipped archives do not settle at C (``experiments.dynamics``), and
in the uneven search the best generator at S is best only in the phase it was scored in: one
NCA iteration later its layout jams (results/warehouse_uneven_a5/investigation). With
``eval.phases: P`` each generator's layouts at iterations C .. C + P - 1 are all scored (repair,
screen, exact runs, each layout as usual: the memo and the screen see layouts, not
generators), and the generator gets the *lowest* of them: a generator ranks by its worse phase.

The layouts of a batch come generator-major (``index = generator * P + phase``). What the
search's policy decides per generator:

- the result-archive elite each phase is compared with is the elite of the generator's cell,
  the cell of its phase C layout (its measures are the generator's);
- exact runs go to all of a generator's fresh phases or none, by the lowest prediction over its
  phases (exact results the memo holds count as they are);
- f_opt and f_res are the lowest over the phases, valid only where every phase is, and the
  result archive takes the generator only where every phase was scored exactly.
"""

from __future__ import annotations

from typing import Any

import numpy as np


def by_generator(values: np.ndarray, phases: int) -> np.ndarray:
    """Per-layout values ``[b * P, ...]`` as ``[b, P, ...]``."""
    values = np.asarray(values)
    return values.reshape(-1, phases, *values.shape[1:])


def first_phase(values: np.ndarray, phases: int) -> np.ndarray:
    """Each generator's phase C value, ``[b, ...]``."""
    return by_generator(values, phases)[:, 0]


def spread(values: np.ndarray, phases: int) -> np.ndarray:
    """A per-generator value ``[b]`` given to each of its phases ``[b * P]``."""
    return np.repeat(np.asarray(values), phases, axis=0)


def lowest(values: np.ndarray, phases: int) -> np.ndarray:
    """The lowest value over each generator's phases (NaN where any phase has none)."""
    return by_generator(values, phases).min(axis=1)


def every(flags: np.ndarray, phases: int) -> np.ndarray:
    """True where every phase of the generator is."""
    return np.asarray(by_generator(flags, phases).all(axis=1))


def combine(
    f_opt: np.ndarray,
    f_res: np.ndarray,
    ok: np.ndarray,
    has_exact: np.ndarray,
    measures: np.ndarray,
    extras: dict[str, Any],
    phases: int,
    failed: float,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, dict[str, Any]]:
    """Per-generator ``(f_opt, f_res, valid, result_valid, measures, extras)`` from per-layout
    ones: the lowest objective over phases, valid where every phase is; measures and per-layout
    extras of phase C, plus ``phase_objective`` ``[b, P]`` (each phase's f_opt)."""
    valid = every(ok, phases)
    result_valid = every(ok & has_exact, phases)
    out_extras = {
        k: (
            v
            if k == "metrics"
            else [v[i] for i in range(0, len(v), phases)]
            if isinstance(v, list)
            else first_phase(v, phases)
        )
        for k, v in extras.items()
    }
    out_extras["phase_objective"] = by_generator(f_opt, phases)
    return (
        np.where(valid, lowest(f_opt, phases), failed),
        np.where(result_valid, lowest(f_res, phases), failed),
        valid,
        result_valid,
        first_phase(measures, phases),
        out_extras,
    )
