"""Records that outlive one evaluation: ``<out>/exact_runs.jsonl`` (exact RHCR runs),
``<out>/screen_runs.jsonl`` (screened runs) and ``<out>/repairs.jsonl`` (repaired layouts).

Exact runs at S_eval cost minutes each, and the screened curves at S_eval hours of batches,
so the paper's protocol (20 runs per layout at 1,400 agents, T=5,000, and a curve over 43
agent counts) may take more than one sitting. Every exact run is appended to its file the
moment it finishes, every screened batch's runs the moment the batch ends (one JSON line per
run, flushed to disk), and a later evaluation into the same folder reuses every recorded run
whose inputs are identical, so an interrupted evaluation (Ctrl-C, SIGTERM, a lost machine once
the files are committed) loses at most the runs in flight.

A run is keyed (:mod:`nca_qd.scoring.keys`) by a digest of everything that decides its outcome:
the layout's rows, the scenario, agent count, T, seed, replan, for RHCR the window and the
planner's options, for the screen its planner, agent order and congestion rule, and the
simulator's ``VERSION`` — so a repaired layout that differs by one tile, or a revised
simulator, never reuses an old run. (A screened run does not depend on the batch it ran in.)
Runs that timed out or failed are not reused (a new attempt may succeed); a run recorded
without its per-step detail does not serve a request that needs it. A truncated last line (a
write cut short) is skipped with a warning.

Runs are keyed by the repaired layout, and the repair runs under a time limit: on a busier
machine it may stop at another valid layout (33x36: Hamming 194 rather than the optimal 140),
which no recorded run serves. So each repair is recorded too, keyed by the layout before repair,
the domain and every repair option, and a later evaluation reuses the recorded layout (after
checking it against the domain's rules) instead of repairing again: the same command goes on
from the same layouts.

Another folder's records may serve too (``records_from``: the other arms of a comparison, whose
human baselines are the same runs): read, never written, and a record used is copied into
this folder's file, so each folder stands alone.

When an evaluation stops — finished, or cut by Ctrl-C, SIGTERM or a campaign's leg — each file's
records are packed into ``<name>.jsonl.gz`` (gzip, one line per key) and the plain journal
``<name>.jsonl`` is removed; the next evaluation reads the packed file, then appends to a new
journal. Packed, the records of a 101x102 evaluation are small enough to ship with the run (a
re-evaluation then screens nothing again), and a screened run keeps its tile visits only where
its cell asked for them (a cell with exact runs draws its heatmap from those).
"""

from __future__ import annotations

import base64
import gzip
import json
import logging
import os
import threading
import zlib
from collections import Counter
from collections.abc import Iterable, Iterator, Mapping, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from nca_qd.scoring.jobs import RunOutcome

if TYPE_CHECKING:
    from nca_qd.scoring.jobs import RepairOutcome

log = logging.getLogger("nca_qd.evaluate")

FILENAME = "exact_runs.jsonl"
SCREEN_FILENAME = "screen_runs.jsonl"
REPAIR_FILENAME = "repairs.jsonl"


def _narrowest(a: np.ndarray) -> np.ndarray:
    """An integer array in the narrowest integer type that holds its values (the same values):
    per-step task counts and tile visits fit in one or two bytes where they are stored as four,
    and a narrower array compresses to about two thirds."""
    if a.dtype.kind not in "iu" or a.size == 0:
        return a
    lo, hi = int(a.min()), int(a.max())
    for t in (np.uint8, np.int8, np.uint16, np.int16, np.uint32, np.int32):
        info = np.iinfo(t)
        if info.min <= lo and hi <= info.max and np.dtype(t).itemsize < a.dtype.itemsize:
            return a.astype(t)
    return a


def _pack(a: np.ndarray | None) -> dict[str, Any] | None:
    """An array as JSON: its dtype and shape, its bytes (in the narrowest integer type that holds
    them, named by ``stored`` where it differs) zlib-compressed and base64-encoded."""
    if a is None:
        return None
    a = np.ascontiguousarray(a)
    narrow = _narrowest(a)
    d: dict[str, Any] = {"dtype": a.dtype.str, "shape": list(a.shape)}
    if narrow.dtype != a.dtype:
        d["stored"] = narrow.dtype.str
    d["zlib_b64"] = base64.b64encode(zlib.compress(narrow.tobytes(), 9)).decode("ascii")
    return d


def _unpack(d: Mapping[str, Any] | None) -> np.ndarray | None:
    """The array :func:`_pack` wrote, in its own dtype (records written before ``stored``
    existed hold the bytes in that dtype)."""
    if d is None:
        return None
    raw = zlib.decompress(base64.b64decode(d["zlib_b64"]))
    stored = np.dtype(d.get("stored", d["dtype"]))
    a = np.frombuffer(raw, dtype=stored).reshape(d["shape"])
    return a.astype(np.dtype(d["dtype"]))


class JsonlRecords:
    """One evaluation folder's JSON-lines file of records by key, loaded once; :meth:`_append`
    adds one, flushed and synced, so a crash keeps it.

    Beside it, ``<name>.superseded.jsonl`` holds the records :meth:`prune` moved out (records
    an evaluation into the folder did not use). They still serve lookups: a later evaluation
    that asks for one gets it, and it moves back into the main file."""

    filename = FILENAME
    what = "recorded run(s)"

    def __init__(self, out: Path, also: Sequence[Path | str] = ()):
        self.path = Path(out) / self.filename
        self._runs: dict[str, dict[str, Any]] = {}
        self._spare: dict[str, dict[str, Any]] = {}  # the superseded file's records
        # other folders' records (``also``: read, never written), for lookups only
        self._borrowed: dict[str, dict[str, Any]] = {}
        self._lent_by: dict[str, Path] = {}  # the folder each borrowed record was read from
        self._origin: dict[str, Path] = {}  # where each record this evaluation found was read
        self._used: set[str] = set()  # keys this evaluation found or added
        self._lock = threading.Lock()
        self._open_line = False  # the file ends inside a line (a write cut short)
        if self.superseded_path.is_file():
            self._spare, _ = self._read(self.superseded_path)
        if self.packed_path.is_file():
            self._runs, _ = self._read(self.packed_path)
        if self.path.is_file():
            journal, self._open_line = self._read(self.path)
            self._runs.update(journal)
        if self._runs:
            log.info("%s: %d %s", self.path.parent, len(self._runs), self.what)
        for folder in also:
            other = Path(folder) / self.filename
            if other.resolve() == self.path.resolve():
                continue
            n = len(self._borrowed)
            for path in (other.with_name(other.name + ".gz"), other):
                if path.is_file():
                    recs = self._read(path)[0]
                    self._borrowed.update(recs)
                    self._lent_by.update(dict.fromkeys(recs, Path(folder)))
            if len(self._borrowed) > n:
                log.info("%s: %d %s to draw on", folder, len(self._borrowed) - n, self.what)

    @property
    def packed_path(self) -> Path:
        """The packed records (:meth:`pack`): ``<name>.jsonl.gz``."""
        return self.path.with_name(self.path.name + ".gz")

    @property
    def superseded_path(self) -> Path:
        """Where :meth:`prune` moves the records an evaluation did not use."""
        return self.path.with_name(self.path.name.replace(".jsonl", ".superseded.jsonl"))

    @staticmethod
    def _read(path: Path) -> tuple[dict[str, dict[str, Any]], bool]:
        """The records of one file by key (a later line wins) and whether it ends inside a line."""
        bad = 0
        recs: dict[str, dict[str, Any]] = {}
        if path.suffix == ".gz":
            try:
                text = gzip.decompress(path.read_bytes()).decode("utf-8", errors="replace")
            except (OSError, EOFError) as exc:
                from nca_qd.errors import NcaQdError

                raise NcaQdError(f"{path}: not a readable gzip file ({exc}); move it aside") from None
        else:
            text = path.read_text(encoding="utf-8", errors="replace")
        for line in text.splitlines():
            if not line.strip():
                continue
            try:
                rec = json.loads(line)
                recs[str(rec["key"])] = rec
            except (ValueError, KeyError, TypeError):
                bad += 1
        if bad:
            log.warning("%s: %d unreadable line(s) skipped (a write cut short?)", path, bad)
        return recs, bool(text) and not text.endswith("\n")

    def __len__(self) -> int:
        return len(self._runs)

    def _find(self, key: str) -> dict[str, Any] | None:
        """The record of ``key`` in the main file, else in the superseded one, else in another
        folder's (which of them is remembered for :meth:`sources`)."""
        if key in self._runs:
            rec, origin = self._runs[key], self.path  # unless copied here from elsewhere (kept below)
        elif key in self._spare:
            rec, origin = self._spare[key], self.superseded_path
        elif key in self._borrowed:
            rec, origin = self._borrowed[key], self._lent_by[key] / self.filename
        else:
            return None
        with self._lock:
            self._origin.setdefault(key, origin)
        return rec

    def sources(self, keys: Iterable[str]) -> str:
        """Where the records of ``keys`` were read from, for a log line: one file, or each file
        with its count (``a/exact_runs.jsonl (12), b/exact_runs.jsonl (3)``). A record read from
        another folder (``records_from``) or the superseded file is named by that file, not by
        this folder's, into which it was copied."""
        counts = Counter(str(self._origin.get(k, self.path)) for k in keys)
        if len(counts) == 1:
            return next(iter(counts))
        return ", ".join(f"{path} ({n})" for path, n in counts.most_common())

    def _use(self, key: str, rec: dict[str, Any]) -> None:
        """Mark a found record as used by this evaluation; one from the superseded file or
        another folder goes into the main file."""
        with self._lock:
            if key not in self._runs:
                self._append(key, rec)
            self._used.add(key)

    def _append(self, key: str, rec: dict[str, Any]) -> None:
        line = json.dumps(rec) + "\n"
        self.path.parent.mkdir(parents=True, exist_ok=True)
        with self.path.open("a", encoding="utf-8") as fh:
            if self._open_line:  # end the cut line, so this record stands on its own
                fh.write("\n")
                self._open_line = False
            fh.write(line)
            fh.flush()
            os.fsync(fh.fileno())
        self._runs[key] = rec
        self._used.add(key)

    def prune(self) -> int:
        """Keep in the main (packed) file only the records this evaluation used (:meth:`pack`);
        the others go to :attr:`superseded_path`, written first, so nothing recorded is lost
        (records of earlier settings: screened runs beside cells that have since got exact runs,
        runs of a layout a changed repair no longer gives). Returns how many records moved.
        Called when an evaluation has ended with every run it asked for: the main file then
        holds what the folder's outputs rest on (what to ship), and the same command repeated
        reuses all of it."""
        from nca_qd.io import atomic_write_text

        with self._lock:
            if not (self.path.is_file() or self.packed_path.is_file()):
                return 0
            moved = {k: r for k, r in self._runs.items() if k not in self._used}
            spare = {k: r for k, r in self._spare.items() if k not in self._runs}
            spare.update(moved)
            if moved:
                atomic_write_text(self.superseded_path, "".join(json.dumps(r) + "\n" for r in spare.values()))
            self._runs = {k: r for k, r in self._runs.items() if k in self._used}
            self._spare = spare
        self.pack()
        if moved:
            log.info(
                "%s: %d record(s) this evaluation did not use moved to %s",
                self.path,
                len(moved),
                self.superseded_path.name,
            )
        return len(moved)

    def _packed_record(self, key: str, rec: dict[str, Any]) -> dict[str, Any]:
        """A record as :meth:`pack` writes it: its arrays packed as :func:`_pack` packs them today."""
        return _repacked(rec)

    def pack(self) -> None:
        """Write every record into :attr:`packed_path` (gzip, one line per key, written
        atomically) and remove the journal. Called when an evaluation stops, finished or cut."""
        from nca_qd.io import atomic_write_bytes

        with self._lock:
            if not (self.path.is_file() or self.packed_path.is_file()):
                return
            self._open_line = False
            if not self._runs:
                self.packed_path.unlink(missing_ok=True)
                self.path.unlink(missing_ok=True)
                return
            self._runs = {k: self._packed_record(k, r) for k, r in self._runs.items()}
            text = "".join(json.dumps(r) + "\n" for r in self._runs.values())
            atomic_write_bytes(self.packed_path, gzip.compress(text.encode("utf-8"), 9, mtime=0))
            self.path.unlink(missing_ok=True)


def _repacked(rec: Mapping[str, Any]) -> dict[str, Any]:
    """A record with its arrays packed as :func:`_pack` packs them today."""
    return {f: (_pack(_unpack(v)) if isinstance(v, dict) and "zlib_b64" in v else v) for f, v in rec.items()}


class RunStore(JsonlRecords):
    """The runs of one simulator recorded in one evaluation folder; :meth:`add` appends.

    A run's detail is its tasks per step (``detail``) and its tile visits; either may be asked
    for. The keys this evaluation asked for without visits (and never with them) are
    remembered: :class:`ScreenRunStore` packs those records without their visits."""

    simulator = "rhcr"

    def __init__(self, out: Path, also: Sequence[Path | str] = ()):
        super().__init__(out, also)
        self._visits_wanted: set[str] = set()
        self._visits_unwanted: set[str] = set()

    def get(self, key: str, need_detail: bool, need_visits: bool | None = None) -> RunOutcome | None:
        """The recorded run for ``key`` if it completed and kept what is needed: its tasks per
        step (``need_detail``) and its tile visits (``need_visits``, by default as
        ``need_detail``)."""
        need_visits = need_detail if need_visits is None else need_visits
        rec = self._find(key)
        if rec is None or rec.get("timed_out") or rec.get("error"):
            return None
        if need_detail and not rec.get("detail"):
            return None
        if need_visits and rec.get("tile_visits") is None:
            return None
        self._use(key, rec)
        with self._lock:
            (self._visits_wanted if need_visits else self._visits_unwanted).add(key)
        return RunOutcome(
            self.simulator,
            int(rec["seed"]),
            float(rec["throughput"]),
            bool(rec["success"]),
            int(rec["stop_time"]),
            False,
            float(rec["seconds"]),
            None,
            _unpack(rec.get("tasks_per_step")),
            _unpack(rec.get("tile_visits")),
        )

    def add(self, key: str, outcome: RunOutcome) -> None:
        """Append one finished run (flushed and synced, so a crash keeps it), with whichever
        detail it carries."""
        detail = outcome.tasks_per_step is not None
        visits = outcome.tile_visits is not None
        rec = {
            "key": key,
            "seed": int(outcome.seed),
            "throughput": float(outcome.throughput),
            "success": bool(outcome.success),
            "stop_time": int(outcome.stop_time),
            "timed_out": bool(outcome.timed_out),
            "seconds": round(float(outcome.seconds), 3),
            "error": outcome.error,
            "detail": detail,
            "tasks_per_step": _pack(outcome.tasks_per_step) if detail else None,
            "tile_visits": _pack(outcome.tile_visits) if visits else None,
        }
        with self._lock:
            if visits:
                self._visits_wanted.add(key)
            old = self._runs.get(key)
            if old is not None and not old.get("error"):
                old_rank = bool(old.get("detail")) + (old.get("tile_visits") is not None)
                if old_rank > detail + visits:
                    return  # never replace a detailed record by a barer one
            self._append(key, rec)


class ExactRunStore(RunStore):
    """Exact RHCR runs: ``exact_runs.jsonl``, keyed by :func:`nca_qd.scoring.keys.exact_run_key`."""


class ScreenRunStore(RunStore):
    """Screened runs: ``screen_runs.jsonl``, keyed by :func:`nca_qd.scoring.keys.screen_run_key`."""

    filename = SCREEN_FILENAME
    simulator = "screen"

    def _packed_record(self, key: str, rec: dict[str, Any]) -> dict[str, Any]:
        """Without its tile visits when this evaluation asked for the run without them (its
        cell has exact runs, whose visits draw the heatmap): most of a 101x102 record's bytes."""
        if key in self._visits_unwanted and key not in self._visits_wanted:
            rec = {**rec, "tile_visits": None}
        return super()._packed_record(key, rec)


class RepairStore(JsonlRecords):
    """Repaired layouts: ``repairs.jsonl``, keyed by :func:`nca_qd.scoring.keys.repair_key`. Only repairs that
    found a layout are recorded (a failed one may succeed on a new attempt)."""

    filename = REPAIR_FILENAME
    what = "recorded repair(s)"

    def get(self, key: str) -> RepairOutcome | None:
        """The recorded repair for ``key``, or None."""
        from nca_qd.scoring.jobs import RepairOutcome

        rec = self._find(key)
        if rec is None:
            return None
        self._use(key, rec)
        hamming = rec.get("hamming")
        layout = _unpack(rec["layout"])
        return RepairOutcome(
            None if layout is None else layout.astype(np.int32),
            str(rec["status"]),
            float(rec["similarity"]),
            None if hamming is None else int(hamming),
            float(rec["seconds"]),
        )

    def adopt_saved(
        self, key: str, item_key: str, unrepaired: np.ndarray, tiles: str
    ) -> RepairOutcome | None:
        """A folder written before ``repairs.jsonl`` existed: the repaired layout it saved for
        ``item_key`` (``layouts/<stem>.json``) when the unrepaired twin it saved beside it
        equals ``unrepaired``, with the figures of its ``layouts.csv`` row; recorded under
        ``key``. None when anything is missing or differs."""
        import csv

        from nca_qd.errors import NcaQdError
        from nca_qd.io import load_map
        from nca_qd.scoring.jobs import RepairOutcome

        folder = self.path.parent
        stem = item_key.replace("@", "_")
        repaired, before = folder / "layouts" / f"{stem}.json", folder / "layouts" / f"{stem}_unrepaired.json"
        table = folder / "layouts.csv"
        if not (repaired.is_file() and before.is_file() and table.is_file()):
            return None
        try:
            was = load_map(before).to_array(tiles)
            layout = load_map(repaired).to_array(tiles)
            with table.open(newline="") as fh:
                row = next((r for r in csv.DictReader(fh) if r.get("file") == f"layouts/{stem}.json"), None)
            if row is None or not np.array_equal(was, np.asarray(unrepaired)):
                return None
            outcome = RepairOutcome(
                layout,
                str(row["repair_status"]),
                float(row["similarity"]),
                int(row["hamming"]),
                float(row["repair_seconds"]),
            )
        except (NcaQdError, OSError, KeyError, TypeError, ValueError):
            return None
        self.add(key, outcome)
        return outcome

    def figures(self) -> Iterator[tuple[np.ndarray, float, int | None]]:
        """The folder's own repairs (main and superseded files, not ``also``'s): each repaired
        layout with its similarity Δ and Hamming distance, for reading a folder's figures
        without the keys that found them (:mod:`nca_qd.compare_top`)."""
        for rec in {**self._spare, **self._runs}.values():
            layout = _unpack(rec.get("layout"))
            if layout is not None:
                hamming = rec.get("hamming")
                yield layout, float(rec["similarity"]), None if hamming is None else int(hamming)

    def add(self, key: str, outcome: RepairOutcome) -> None:
        """Append one repair that found a layout (flushed and synced)."""
        if outcome.layout is None:
            return
        rec = {
            "key": key,
            "status": outcome.status,
            "similarity": float(outcome.similarity),
            "hamming": None if outcome.hamming is None else int(outcome.hamming),
            "seconds": round(float(outcome.seconds), 3),
            "layout": _pack(np.asarray(outcome.layout, dtype=np.int8)),
        }
        with self._lock:
            self._append(key, rec)
