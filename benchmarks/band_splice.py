"""Copy bands of rows from one layout into another: a layout with one's feature and the other's rest.

    python -m benchmarks.band_splice results/warehouse_even_qd/league_140x500/nca_c4472_140x500.json \
        results/warehouse_even_qd/league_140x500/tiling_c4472_140x500.json \
        --copy 22-31:23-32 --copy 56-65:56-65 --copy 88-97:89-98 --copy 122-131:122-131 \
        --keep-cols 2 --out /tmp/grown_with_bands_unrepaired.json

To tell whether a feature of one layout (the tiling's bands where its tiles meet) is what makes
it move more tasks than another (the grown layout), put the feature into the other layout and
run both. ``--copy T0-T1:S0-S1`` writes source rows S0..S1 over target rows T0..T1 (inclusive,
the same number of rows; a one-row shift keeps a band's shelf rows where the target has its
own); ``--keep-cols N`` keeps the target's first and last N columns (a warehouse's workstation
frame, 2 columns a side, which alternates by row). The result is written unrepaired with its
shelf count printed; repair it to the target's shelf count (``python -m experiments.repair
... n_shelves=<count>``) so both hold the same storage, then simulate both. Bad input (a missing
file, a different map size, ranges that overlap, differ in length or leave the map): one line on
stderr, exit status 2.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from benchmarks.cli import guarded
from nca_qd.errors import NcaQdError
from nca_qd.io import MapFile, load_map, save_map


def parse_copy(spec: str, n_rows: int) -> tuple[range, range]:
    """``"T0-T1:S0-S1"`` -> (target rows, source rows), inclusive ranges of equal length."""
    try:
        target, source = (tuple(int(x) for x in part.split("-")) for part in spec.split(":"))
        t0, t1 = target
        s0, s1 = source
    except ValueError:
        raise NcaQdError(f"--copy {spec!r}: expected T0-T1:S0-S1 (row numbers)") from None
    if t1 - t0 != s1 - s0 or t1 < t0:
        raise NcaQdError(f"--copy {spec!r}: the two ranges must hold the same number of rows")
    if min(t0, s0) < 0 or max(t1, s1) >= n_rows:
        raise NcaQdError(f"--copy {spec!r}: rows run from 0 to {n_rows - 1}")
    return range(t0, t1 + 1), range(s0, s1 + 1)


def splice(
    target: list[str], source: list[str], copies: list[tuple[range, range]], keep_cols: int = 0
) -> list[str]:
    """``target``'s rows with each copy's source rows written over its target rows, but for the
    first and last ``keep_cols`` columns, which stay the target's."""
    out = list(target)
    taken: set[int] = set()
    for t_rows, s_rows in copies:
        if taken & set(t_rows):
            raise NcaQdError(f"--copy ranges overlap at target rows {sorted(taken & set(t_rows))}")
        taken |= set(t_rows)
        for t, s in zip(t_rows, s_rows):
            k, w = keep_cols, len(target[t])
            out[t] = target[t][:k] + source[s][k : w - k] + target[t][w - k :]
    return out


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("target", type=Path, help="the layout that receives the rows")
    p.add_argument("source", type=Path, help="the layout the rows come from")
    p.add_argument("--copy", action="append", required=True, help="T0-T1:S0-S1, repeatable")
    p.add_argument("--keep-cols", type=int, default=0, help="columns a side that stay the target's")
    p.add_argument("--out", type=Path, required=True)
    args = p.parse_args(argv)
    return guarded(lambda: _splice_file(args))


def _splice_file(args: argparse.Namespace) -> None:
    target, source = load_map(args.target), load_map(args.source)
    if target.shape != source.shape:
        raise NcaQdError(f"{args.target} is {target.shape}, {args.source} is {source.shape}")
    copies = [parse_copy(c, target.shape[0]) for c in args.copy]
    if not 0 <= args.keep_cols < target.shape[1] // 2:
        top = target.shape[1] // 2 - 1
        raise NcaQdError(f"--keep-cols must be from 0 to {top}, got {args.keep_cols}")
    rows = splice(target.rows, source.rows, copies, args.keep_cols)
    extra = {
        "spliced": {
            "target": args.target.name,
            "source": args.source.name,
            "copies": args.copy,
            "keep_cols": args.keep_cols,
        }
    }
    save_map(args.out, MapFile(args.out.stem, rows, extra))
    count = sum(r.count("@") for r in rows)
    before = sum(r.count("@") for r in target.rows)
    print(json.dumps({"out": str(args.out), "shelves": count, "target_shelves": before}))


if __name__ == "__main__":
    raise SystemExit(main())
