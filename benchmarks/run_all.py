"""``make bench``: every benchmark section in turn (each prints its own figures).

python -m benchmarks.run_all [section ...]

sections: foundation, maze_rollout, rhcr, work_cap, repair, screen, search, checkpoint, dsage
"""

from __future__ import annotations

import importlib
import inspect
import sys
import time

SECTIONS = [
    "foundation",
    "maze_rollout",
    "rhcr",
    "work_cap",
    "repair",
    "screen",
    "search",
    "checkpoint",
    "dsage",
]


def main(argv: list[str]) -> int:
    chosen = argv or SECTIONS
    unknown = [s for s in chosen if s not in SECTIONS]
    if unknown:
        print(f"error: unknown benchmark section(s) {unknown} (known: {SECTIONS})", file=sys.stderr)
        return 2
    for name in chosen:
        try:
            module = importlib.import_module(f"benchmarks.bench_{name}")
        except ModuleNotFoundError:
            print(f"== {name}: not available in this checkout ==")
            continue
        t0 = time.perf_counter()
        # each section with its defaults (its options are for running it alone; without an
        # explicit empty list argparse would read run_all's own arguments)
        takes_argv = bool(inspect.signature(module.main).parameters)
        module.main([]) if takes_argv else module.main()
        print(f"== {name}: {time.perf_counter() - t0:.0f} s ==", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
