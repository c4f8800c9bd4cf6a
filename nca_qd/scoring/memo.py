"""Remember what a search already paid for: the repair of each generated layout and the exact
RHCR runs of each repaired layout.

Why: an NCA turns continuous parameters into discrete tiles, so nearby CMA-ES samples often
generate the *same* layout. Measured on the warehouse (even) search at its first iteration,
a 50-solution batch held 26-30 distinct generated layouts (4-10 per emitter of 10). Without
a memo every copy is repaired and simulated again (the two stages are ~95 % of an iteration),
and a copy that draws luckier RHCR seeds replaces its own elite in the result archive: the
archive keeps the maximum of noisy re-draws of one layout. With the memo a layout's objective
is a function of the layout (its first exact runs), each layout costs once, and copies in one
batch share one set of jobs.

Keys are SHA-1 digests of the layout's shape and tiles. Entries record the iteration that
made them, so a resumed run drops those made after its checkpoint and replays exactly.
Failed jobs (errors, dead workers) are not remembered: they may succeed when tried again.
"""

from __future__ import annotations

import logging
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np

from nca_qd.io import save_npz
from nca_qd.scoring.jobs import RepairOutcome

log = logging.getLogger(__name__)

MEMO_FILE = "eval_memo.npz"
DIGEST_SIZE = 20  # SHA-1


def _key_array(keys: list[bytes]) -> np.ndarray:
    """Digests as a ``uint8 [n, 20]`` array (numpy's bytes strings would drop trailing zeros)."""
    return np.frombuffer(b"".join(keys), dtype=np.uint8).reshape(len(keys), DIGEST_SIZE)


def first_of_each(keys: list[bytes]) -> tuple[np.ndarray, np.ndarray]:
    """``(first, inverse)``: the index of each distinct key's first occurrence, and for each
    position the index into ``first`` of its key (so ``keys[first[inverse[i]]] == keys[i]``)."""
    seen: dict[bytes, int] = {}
    first, inverse = [], []
    for i, k in enumerate(keys):
        if k not in seen:
            seen[k] = len(first)
            first.append(i)
        inverse.append(seen[k])
    return np.asarray(first, dtype=np.int64), np.asarray(inverse, dtype=np.int64)


class EvalMemo:
    """Repairs by generated layout, exact throughputs (one per seed) by repaired layout.

    ``fingerprint`` names the settings the remembered values depend on (domain, agents, T,
    runs, repair options): a file written under other settings is not used."""

    def __init__(self, fingerprint: str):
        self.fingerprint = fingerprint
        self._repairs: dict[bytes, tuple[RepairOutcome, int]] = {}
        self._exact: dict[bytes, tuple[np.ndarray, int]] = {}
        self._visits: dict[bytes, np.ndarray] = {}  # tile usage of the exact runs, if recorded
        # per exact entry: each run's verdict and the layout's free-flow throughput, where
        # recorded (they calibrate the screen's free-flow estimate; older memos lack them)
        self._flow: dict[bytes, tuple[np.ndarray, float]] = {}

    def __len__(self) -> int:
        return len(self._repairs) + len(self._exact)

    # --- look-ups ------------------------------------------------------------------------
    def repair(self, key: bytes) -> RepairOutcome | None:
        hit = self._repairs.get(key)
        return None if hit is None else hit[0]

    def exact(self, key: bytes) -> np.ndarray | None:
        """The per-seed exact throughputs of a repaired layout, or None."""
        hit = self._exact.get(key)
        return None if hit is None else hit[0]

    def visits(self, key: bytes) -> np.ndarray | None:
        """The mean tile usage of a repaired layout's exact runs, if they recorded it."""
        return self._visits.get(key)

    def put_repair(self, key: bytes, rep: RepairOutcome, iteration: int) -> None:
        if rep.status != "error":  # an error (a crash, a dead worker) may not recur
            self._repairs.setdefault(key, (rep, int(iteration)))

    def put_exact(
        self,
        key: bytes,
        throughputs: np.ndarray,
        iteration: int,
        visits: np.ndarray | None = None,
        success: np.ndarray | None = None,
        free_flow: float | None = None,
    ) -> None:
        """Remember a layout's exact runs (all of them finished); optionally their tile usage,
        each run's verdict and the layout's free-flow throughput."""
        tp = np.asarray(throughputs, dtype=np.float64)
        if np.isfinite(tp).all() and key not in self._exact:  # a failed run is not a result
            self._exact[key] = (tp, int(iteration))
            if visits is not None:
                self._visits[key] = np.asarray(visits, np.float16)
            if success is not None and free_flow is not None and np.isfinite(free_flow):
                self._flow[key] = (np.asarray(success, bool).reshape(tp.shape), float(free_flow))

    def flowing_shares(self) -> np.ndarray:
        """Exact throughput over free flow of every remembered run that flowed (RHCR's verdict),
        on the layouts whose verdicts and free flow were recorded."""
        shares = [
            self._exact[k][0][ok] / flow
            for k, (ok, flow) in self._flow.items()
            if k in self._exact and flow > 0
        ]
        return np.concatenate(shares) if shares else np.zeros(0)

    # --- on disk -------------------------------------------------------------------------
    def to_arrays(self) -> dict[str, np.ndarray]:
        found = [r.layout.shape for r, _ in self._repairs.values() if r.layout is not None]
        shape = max(set(found), key=found.count) if found else (0, 0)
        # One run repairs one size; an entry of another shape (none in practice) is dropped
        # rather than stored wrongly: forgetting it only costs a repair.
        reps = [
            (k, r, it) for k, (r, it) in self._repairs.items() if r.layout is None or r.layout.shape == shape
        ]
        layouts = np.zeros((len(reps), *shape), dtype=np.int8)
        for i, (_, r, _) in enumerate(reps):
            if r.layout is not None:
                layouts[i] = r.layout
        exact = [(k, tp, it) for k, (tp, it) in self._exact.items()]
        n_runs = len(exact[0][1]) if exact else 0
        visits = {}
        if self._visits:  # only runs that record tile usage (DSAGE's ancillary target)
            vshape = next(iter(self._visits.values())).shape
            vis = np.full((len(exact), *vshape), np.nan, np.float16)
            for i, (k, _, _) in enumerate(exact):
                v = self._visits.get(k)
                if v is not None and v.shape == vshape:
                    vis[i] = v
            visits = {"exact_visits": vis}
        # -1: not recorded
        success = np.full((len(exact), n_runs), -1, np.int8)
        flow = np.full(len(exact), np.nan)
        for i, (k, _, _) in enumerate(exact):
            if k in self._flow:
                success[i], flow[i] = self._flow[k]
        return {
            **visits,
            "exact_success": success,
            "exact_free_flow": flow,
            "fingerprint": np.asarray(self.fingerprint),
            "repair_keys": _key_array([k for k, _, _ in reps]),
            "repair_layouts": layouts,
            "repair_found": np.asarray([r.layout is not None for _, r, _ in reps], dtype=bool),
            "repair_status": np.asarray([r.status for _, r, _ in reps], dtype=str),
            "repair_similarity": np.asarray([r.similarity for _, r, _ in reps], np.float64),
            "repair_hamming": np.asarray(
                [-1 if r.hamming is None else r.hamming for _, r, _ in reps], np.int64
            ),
            "repair_iteration": np.asarray([it for _, _, it in reps], np.int64),
            "exact_keys": _key_array([k for k, _, _ in exact]),
            "exact_throughput": np.asarray([tp for _, tp, _ in exact], np.float64).reshape(
                len(exact), n_runs
            ),
            "exact_iteration": np.asarray([it for _, _, it in exact], np.int64),
        }

    def save(self, path: str | Path) -> None:
        """Write the memo atomically (readers see the old file or the new one)."""
        save_npz(path, self.to_arrays())

    @classmethod
    def from_arrays(
        cls, arrays: Mapping[str, Any], fingerprint: str, upto_iteration: int | None = None
    ) -> EvalMemo:
        """The memo saved in ``arrays``, keeping entries made up to ``upto_iteration`` (a
        resumed run's checkpoint); empty if it was written under another fingerprint."""
        memo = cls(fingerprint)
        if str(arrays["fingerprint"]) != fingerprint:
            log.warning("evaluation memo was written under other settings; starting a new one")
            return memo
        keep = (lambda it: True) if upto_iteration is None else (lambda it: it <= upto_iteration)
        for i, key in enumerate(arrays["repair_keys"]):
            it = int(arrays["repair_iteration"][i])
            if keep(it):
                ham = int(arrays["repair_hamming"][i])
                rep = RepairOutcome(
                    np.asarray(arrays["repair_layouts"][i], np.int32) if arrays["repair_found"][i] else None,
                    str(arrays["repair_status"][i]),
                    float(arrays["repair_similarity"][i]),
                    None if ham < 0 else ham,
                    seconds=0.0,
                )
                memo._repairs[np.asarray(key, np.uint8).tobytes()] = (rep, it)
        for i, key in enumerate(arrays["exact_keys"]):
            it = int(arrays["exact_iteration"][i])
            if keep(it):
                tp = np.asarray(arrays["exact_throughput"][i])
                k = np.asarray(key, np.uint8).tobytes()
                memo._exact[k] = (tp, it)
                if "exact_visits" in arrays and np.isfinite(arrays["exact_visits"][i]).all():
                    memo._visits[k] = np.asarray(arrays["exact_visits"][i], np.float16)
                if "exact_free_flow" in arrays and np.isfinite(arrays["exact_free_flow"][i]):
                    ok = np.asarray(arrays["exact_success"][i])
                    if (ok >= 0).all():
                        memo._flow[k] = (ok.astype(bool), float(arrays["exact_free_flow"][i]))
        return memo

    @classmethod
    def load(cls, path: str | Path, fingerprint: str, upto_iteration: int | None = None) -> EvalMemo:
        """Read ``path`` (a missing or unreadable file gives an empty memo: it only saves time)."""
        path = Path(path)
        if not path.is_file():
            return cls(fingerprint)
        try:
            with np.load(path) as data:
                return cls.from_arrays({k: data[k] for k in data.files}, fingerprint, upto_iteration)
        except (OSError, ValueError, KeyError) as exc:
            log.warning("%s: unreadable evaluation memo (%s); starting a new one", path, exc)
            return cls(fingerprint)
