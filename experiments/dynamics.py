"""Does each NCA generator of a run settle at the iterations it is scored at?

    python -m experiments.dynamics run_dir=results/warehouse_uneven_a5 [size=eval] [top=100] [out=d.csv]

Prints the share of still / travelling / period-2 / other generators among the elites looked
at and among the 10 best, and the 10 best one per line; ``out=`` writes one CSV row per elite
(``nca_qd.dynamics`` defines the kinds). In the warehouse and manufacturing domains it also
prints how far each elite's layout at C (before repair) is from the domain's count rules at
that size (the shelves a warehouse needs, the traversable tiles for its robots): a generator
that settles can still grow a layout the repair has to redraw. Bad input: one line on stderr,
exit status 2.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from experiments.cli import check_writable, compose_config, main_guard
from nca_qd.dynamics import Thresholds, classify, count_misses, summarise
from nca_qd.errors import NcaQdError
from nca_qd.io import atomic_write_text

COLUMNS = (
    "cell",
    "objective",
    "kind",
    "changed_1",
    "changed_2",
    "moved_mismatch_1",
    "moved_mismatch_2",
    "share_swing",
    "tied",
)


def main(argv: list[str]) -> int:
    cfg = compose_config("dynamics", argv)
    if not cfg.run_dir:
        raise NcaQdError("give run_dir=<a run directory>")
    if cfg.size not in ("train", "eval"):
        raise NcaQdError(f"size must be train or eval, got {cfg.size!r}")
    for key in ("extra", "batch", "max_shift"):
        if not isinstance(cfg[key], int) or cfg[key] < (2 if key == "extra" else 1):
            raise NcaQdError(f"{key} must be an integer >= {2 if key == 'extra' else 1}, got {cfg[key]!r}")
    if cfg.top is not None and (not isinstance(cfg.top, int) or cfg.top < 1):
        raise NcaQdError(f"top must be a positive integer or null, got {cfg.top!r}")
    out = Path(cfg.out) if cfg.out else None
    if out is not None:
        check_writable(out, "out")

    from nca_qd.domains import make_domain
    from nca_qd.evaluation.layouts import load_run
    from nca_qd.pipeline import make_generator
    from nca_qd.run_dir import select_elites

    run_cfg, archive = load_run(cfg.run_dir, command="experiments.dynamics")
    domain = make_domain(run_cfg["domain"])
    generator = make_generator(domain)
    objective = np.asarray(archive["objective"])
    n_elites = int(np.isfinite(objective).sum())
    top = cfg.top if cfg.top is not None else (n_elites if cfg.size == "train" else 100)
    cells = select_elites(objective, min(top, n_elites))
    genotypes = np.asarray(archive["genotypes"])[cells]
    shape, n_iters = domain.gen_shape(cfg.size), domain.nca_iters(cfg.size)
    seed = domain.seed(shape)
    th = Thresholds(float(cfg.tol), float(cfg.shift_tol), int(cfg.max_shift))
    counts = _count_rules(run_cfg["domain"], domain, cfg.size)
    rows = []
    for i in range(0, len(cells), int(cfg.batch)):
        layouts, tied = generator.trajectory(genotypes[i : i + cfg.batch], seed, n_iters, int(cfg.extra))
        for j, cell in enumerate(cells[i : i + cfg.batch]):
            row = {"cell": int(cell), "objective": float(objective[cell]), "tied": float(tied[j])}
            row.update(classify(layouts[j], domain.n_tiles, th))
            if counts:
                misses = count_misses(domain.assemble(layouts[j][0]), counts)
                row.update({_slug(m["name"]): m["got"] for m in misses})
                row["count_miss"] = max(float(m["miss"]) for m in misses)
            rows.append(row)
    where = f"{shape[0]}x{shape[1]}, C={n_iters}..{n_iters + cfg.extra}"
    for label, part in (("elites", rows), ("10 best", rows[:10])):
        shares = summarise([r["kind"] for r in part])
        print(f"{label} ({len(part)}, {where}): " + ", ".join(f"{k} {v:.1%}" for k, v in shares.items()))
    for r in rows[:10]:
        print(
            f"  cell {r['cell']} f={r['objective']:.2f} {r['kind']}: changed {r['changed_1']:.2f} / "
            f"{r['changed_2']:.2f} (C+1 / C+2), moved {r['moved_mismatch_1']:.2f} / "
            f"{r['moved_mismatch_2']:.2f}, tile share swing {r['share_swing']:.2f}, tied {r['tied']:.2f}"
        )
    for rule in counts:
        _print_counts(rule, rows, where)
    if out is not None:
        columns = COLUMNS + ((*(_slug(r.name) for r in counts), "count_miss") if counts else ())
        lines = [",".join(columns)]
        lines += [",".join(_fmt(r[c]) for c in columns) for r in rows]
        atomic_write_text(out, "\n".join(lines) + "\n")
        print(f"wrote {out}")
    return 0


def _count_rules(domain_cfg, domain, which: str) -> tuple:
    """The domain's count rules at size ``which`` (its config's shelf and agent counts), or ()
    for a domain without them (the maze)."""
    from nca_qd.domains.multiagent import MultiAgentDomain
    from nca_qd.repair import make_rules

    if not isinstance(domain, MultiAgentDomain):
        return ()
    shape = domain.assemble(np.zeros(domain.gen_shape(which), dtype=np.int32)).shape
    n_shelves = ((domain_cfg.get("repair") or {}).get("n_shelves") or {}).get(which)
    n_agents = int((domain_cfg.get("n_agents") or {}).get(which) or 1)
    return make_rules(domain.name, shape, n_shelves=n_shelves, n_agents=n_agents).counts


def _print_counts(rule, rows: list[dict], where: str) -> None:
    """One line per count rule: the elites' counts before repair against the rule's value."""
    key = _slug(rule.name)
    for label, part in (("elites", rows), ("10 best", rows[:10])):
        got = np.array([r[key] for r in part])
        if rule.op == ">=":
            near = int((got >= rule.value).sum())
            holds = "hold it"
        else:
            near = int((np.abs(got - rule.value) <= 0.1 * rule.value).sum())
            holds = "within 10 %"
        print(
            f"{rule.name} {rule.op} {rule.value:,} before repair, {label} ({len(part)}, {where}): "
            f"median {np.median(got):,.0f} (range {got.min():,}-{got.max():,}); "
            f"{holds}: {near} of {len(part)}"
        )


def _slug(name: str) -> str:
    return name.replace(" ", "_")


def _fmt(v) -> str:
    return f"{v:.6g}" if isinstance(v, float) else str(v)


if __name__ == "__main__":
    main_guard(main)()
