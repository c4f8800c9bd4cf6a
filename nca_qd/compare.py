"""Compare QD algorithms across seeds: the paper's QD-score / coverage table and curves.

Reads run directories (each with ``config.yaml`` and ``metrics.csv``), groups them by domain
(with its measures) and algorithm, and reports for each group the final QD-score and coverage
of the result archive as mean +- standard error over its runs (the paper's appendix table), and
both over evaluations with 95 % confidence intervals (Student t over the runs) on a common grid
of evaluations (each run's curve is a step function: what its archive held after each
iteration).
"""

from __future__ import annotations

import csv
import math
import warnings
from collections import defaultdict
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from nca_qd.errors import NcaQdError
from nca_qd.paper import (
    DSAGE_MULTI_AGENT_PARTS,
    DSAGE_MULTI_AGENT_SETTINGS,
    DSAGE_SETTINGS,
    MAP_ELITES_SETTINGS,
)
from nca_qd.paper import QD_EVALUATIONS as PAPER_EVALUATIONS
from nca_qd.paper import QD_TABLE as PAPER_TABLE
from nca_qd.run_dir import ELITES_FILE, METRICS_FILE, load_run_config

METRICS = ("qd_score", "coverage")


@dataclass
class RunCurve:
    """One run's result-archive metrics after each iteration."""

    path: Path
    group: tuple[str, str]  # (domain with measures, algorithm)
    seed: int
    evaluations: np.ndarray
    values: dict[str, np.ndarray]


class NotStarted(NcaQdError):
    """A run directory whose search has not finished an iteration yet."""


def read_run(run_dir: str | Path) -> RunCurve:
    """A run directory's curve; one clear error when it is not a run with metrics."""
    from omegaconf import OmegaConf

    run_dir = Path(run_dir)
    cfg = load_run_config(run_dir)
    path = run_dir / METRICS_FILE
    if not path.is_file():
        raise NcaQdError(f"{run_dir}: no {METRICS_FILE}")
    with path.open() as fh:
        rows = list(csv.DictReader(fh))
    if not rows:
        raise NotStarted(f"{run_dir}: {METRICS_FILE} has no iterations yet")
    check_against_record(run_dir, cfg, rows[-1])
    measures = "+".join(cfg.domain.measures.names)
    evaluations = np.asarray([float(r["evaluations"]) for r in rows])
    label = algorithm_label(cfg)
    budget = OmegaConf.select(cfg, "qd.n_evals", default=None)
    if budget is not None and evaluations[-1] < float(budget):
        # a search still under way (a campaign's arm between legs) is a row of its own: pooled
        # with its finished seeds, its figures would pull their mean down
        label += f" (in progress: seed {int(cfg.seed)}, {evaluations[-1]:,.0f} of {int(budget):,})"
    return RunCurve(
        path=run_dir,
        group=(f"{cfg.domain.name} ({measures})", label),
        seed=int(cfg.seed),
        evaluations=evaluations,
        values={m: np.asarray([float(r[m]) for r in rows]) for m in METRICS},
    )


def check_against_record(run_dir: Path, cfg, last: dict[str, str]) -> None:
    """Where a run ships its elites record (written with its archives at the end), its last
    metrics row must be that archive's: QD-score (sum of objective minus the domain's lower
    bound) and coverage recounted from the record, independently of the search's own sums."""
    path = run_dir / ELITES_FILE
    if not path.is_file():
        return
    with np.load(path) as record:
        objective, n_cells = record["objective"].astype(np.float64), int(np.prod(record["grid_cells"]))
    offset = float(cfg.domain.objective_range[0])
    qd, coverage = float((objective - offset).sum()), objective.size / n_cells
    said_qd, said_cov = float(last["qd_score"]), float(last["coverage"])
    if not (math.isclose(qd, said_qd, rel_tol=1e-5, abs_tol=1e-2) and abs(coverage - said_cov) < 1e-6):
        raise NcaQdError(
            f"{run_dir}: {METRICS_FILE}'s last row (QD-score {said_qd:,.2f}, coverage {said_cov:.6f}) "
            f"is not its {ELITES_FILE}'s archive (QD-score {qd:,.2f}, coverage {coverage:.6f})"
        )


def algorithm_label(cfg) -> str:
    """The algorithm and, in a domain whose objective has the repair term ``f + α·Δ``, its α:
    arms that differ in α are different arms (the paper's table 2 compares α = 0, 1, 5). A maze
    run measured by another agent than the shipped one (``domain.agent``: another kind or other
    weights) is another arm too: its path-length measure is that agent's."""
    from omegaconf import OmegaConf

    alpha = OmegaConf.select(cfg, "alpha", default=None)
    if alpha is None:
        alpha = OmegaConf.select(cfg, "domain.alpha", default=None)
    name = str(cfg.algo.name)
    label = name if alpha is None else f"{name} α={float(alpha):g}"
    if name == "dsage":
        label += dsage_variant(cfg)
    if name == "map_elites":
        label += map_elites_variant(cfg)
    kind = OmegaConf.select(cfg, "domain.agent.kind", default=None)
    weights = OmegaConf.select(cfg, "domain.agent.weights", default=None)
    if kind is not None and (kind != "learned" or weights not in (None, "")):
        label += f", agent {kind}" + ("" if weights in (None, "") else f" ({Path(str(weights)).name})")
    return label


def map_elites_variant(cfg) -> str:
    """`` (not the paper's: elitist archive, n_initial 100, initial_sigma 0.2)`` for a MAP-Elites
    run set otherwise than the paper's code ran it (:data:`nca_qd.paper.MAP_ELITES_SETTINGS`,
    the archive ``algo.archive=auto`` gives its domain), so that its row is its own arm; ""
    for the paper's."""
    from omegaconf import OmegaConf

    from nca_qd.qd.loop import map_elites_archive

    archive = map_elites_archive(cfg.algo, cfg.domain)
    differs = [] if archive == map_elites_archive({"archive": "auto"}, cfg.domain) else [f"{archive} archive"]
    for key, paper in MAP_ELITES_SETTINGS.items():
        value = OmegaConf.select(cfg, f"algo.{key}", default=None)
        if value is not None and float(value) != paper:
            differs.append(f"{key} {value:g}")
    return f" (not the paper's: {', '.join(differs)})" if differs else ""


def dsage_variant(cfg) -> str:
    """What sets a DSAGE run apart from the paper's DSAGE row of its domain, so that its row is
    its own arm: in the maze, `` (reduced: surrogate.epochs 20 of 200, …)`` for settings below
    DSAGE's public ones (:data:`nca_qd.paper.DSAGE_SETTINGS`; a CPU run at them costs hours per
    outer iteration), beside the paper's row; in the warehouse and manufacturing domains, whose
    paper DSAGE has parts this one lacks (:data:`nca_qd.paper.DSAGE_MULTI_AGENT_PARTS`), always
    `` (not the paper's: lacks <parts>; inner.batch_size 30 for 10, …)`` with no paper row beside it;
    "" for a maze run at DSAGE's settings."""
    from omegaconf import OmegaConf

    def value(key):
        return OmegaConf.select(cfg, f"algo.{key}", default=None)

    domain = str(OmegaConf.select(cfg, "domain.name", default="maze"))
    if not domain.startswith("maze"):
        differs = [
            f"{key} {value(key):,} for {paper:,}"
            for key, paper in DSAGE_MULTI_AGENT_SETTINGS.items()
            if value(key) is not None and float(value(key)) != paper
        ]
        missing = "lacks " + ", ".join(DSAGE_MULTI_AGENT_PARTS)
        return f" (not the paper's: {'; '.join([missing, *([', '.join(differs)] if differs else [])])})"
    cut = [
        f"{key} {value(key):,} of {full:,}"
        for key, full in DSAGE_SETTINGS.items()
        if value(key) is not None and float(value(key)) < full
    ]
    return f" (reduced: {', '.join(cut)})" if cut else ""


def find_runs(paths: Iterable[str | Path]) -> list[Path]:
    """Each path that is a run directory, or the run directories below it."""
    found: list[Path] = []
    for p in paths:
        p = Path(p)
        if not p.exists():
            raise NcaQdError(f"{p} does not exist")
        if (p / METRICS_FILE).is_file():
            found.append(p)
        else:
            found += sorted(m.parent for m in p.rglob(METRICS_FILE))
    if not found:
        raise NcaQdError(f"no run directories (with {METRICS_FILE}) in {[str(p) for p in paths]}")
    return found


def read_runs(paths: Iterable[str | Path]) -> tuple[list[RunCurve], list[Path]]:
    """The curves of the runs at ``paths`` and the runs found below a folder that have no
    iteration yet (an arm a campaign has just started: left out and named, not an error; a run
    named itself must have one)."""
    named = {Path(p) for p in paths}
    curves, waiting = [], []
    for run in find_runs(paths):
        try:
            curves.append(read_run(run))
        except NotStarted:
            if run in named:
                raise
            waiting.append(run)
    if not curves:
        raise NcaQdError(f"no run with iterations yet in {[str(p) for p in paths]}")
    return curves, waiting


def _t95(n: int) -> float:
    """Two-sided 95 % Student t quantile for n - 1 degrees of freedom (normal beyond 30)."""
    table = {1: 12.706, 2: 4.303, 3: 3.182, 4: 2.776, 5: 2.571, 6: 2.447, 7: 2.365, 8: 2.306, 9: 2.262}
    if n - 1 in table:
        return table[n - 1]
    return 2.0 if n - 1 < 30 else 1.96


def mean_se(values: Sequence[float]) -> tuple[float, float]:
    """Mean and standard error (0 for a single run)."""
    v = np.asarray(values, float)
    return float(v.mean()), float(v.std(ddof=1) / math.sqrt(v.size)) if v.size > 1 else 0.0


def step_values(curve: RunCurve, metric: str, grid: np.ndarray) -> np.ndarray:
    """The run's metric at each evaluation count of ``grid`` (NaN before its first iteration)."""
    idx = np.searchsorted(curve.evaluations, grid, side="right") - 1
    out = np.where(idx >= 0, curve.values[metric][np.maximum(idx, 0)], np.nan)
    return out


@dataclass
class GroupSummary:
    group: tuple[str, str]
    runs: list[RunCurve]
    final: dict[str, tuple[float, float]]  # metric -> (mean, s.e.) at the runs' last iteration
    evaluations: float  # the smallest final evaluation count among the runs


def summarise(curves: Sequence[RunCurve]) -> list[GroupSummary]:
    """One summary per (domain, algorithm) group, ordered by domain then by final QD-score."""
    groups: dict[tuple[str, str], list[RunCurve]] = defaultdict(list)
    for c in curves:
        groups[c.group].append(c)
    out = []
    for group, runs in groups.items():
        final = {m: mean_se([r.values[m][-1] for r in runs]) for m in METRICS}
        out.append(GroupSummary(group, runs, final, float(min(r.evaluations[-1] for r in runs))))
    return sorted(out, key=lambda s: (s.group[0], -s.final["qd_score"][0]))


def paper_row(group: tuple[str, str], evaluations: float) -> str:
    """The paper's table 4 figures for a group, as the table's last column: the same domain and
    algorithm, measured by the shipped agent or by the paper's own as its search played it
    (``paper_accel_search``: the agent behind the paper's rows), not by other weights; with the
    paper's budget beside it where the run's differs (a 10,000-evaluation run is not set beside
    a 100,000 row unmarked); a reduced DSAGE's row says the paper's ran at DSAGE's settings."""
    paper, reduced = _paper_qd(group)
    if paper is None:
        return "—"
    text = f"{paper[0][0]:,.2f} ± {paper[0][1]:,.2f} / {paper[1][0]:.2f} ± {paper[1][1]:.2f}"
    if reduced:
        text += " (DSAGE's full settings)"
    if not _paper_budget(group, evaluations):
        text += f" (at {PAPER_EVALUATIONS[group[0].split(' (')[0]]:,} evaluations: not this run's budget)"
    return text


def _paper_qd(group: tuple[str, str]) -> tuple[tuple[tuple[float, float], tuple[float, float]] | None, bool]:
    """The paper's table 4 entry for a group (None where its agent's measure is not the
    paper's, or the paper has none) and whether the group is a reduced DSAGE of it."""
    domain, label = group
    algorithm, _, agent = label.partition(", agent ")
    if agent and not agent.startswith("paper_accel_search"):
        return None, False
    algorithm, reduced, _ = algorithm.partition(" (reduced: ")
    return PAPER_TABLE.get((domain, algorithm)), bool(reduced)


def _paper_budget(group: tuple[str, str], evaluations: float) -> bool:
    """Whether a group ran the paper's budget of evaluations (within 1 %; true where unknown)."""
    budget = PAPER_EVALUATIONS.get(group[0].split(" (")[0])
    return budget is None or abs(evaluations - budget) <= 0.01 * budget


# Issue 55's bound for table 4: a QD-score more than 2 standard errors of the difference from
# the paper's mean differs.
QD_SE_BOUND = 2.0


def qd_against_paper(summary: GroupSummary) -> str:
    """Whether the group's final QD-score is within :data:`QD_SE_BOUND` standard errors of the
    difference from the paper's mean ("within"), or by how much it is not ("differs: ...");
    "—" where :func:`paper_row` sets no comparable row beside it (another agent's measure, a
    reduced DSAGE, another budget, no paper row). The error of the difference is
    sqrt(se_ours² + se_paper²); a single run has no s.e. of its own, so the paper's spread of
    one run stands for it (its s.e. times sqrt(5), the paper's runs)."""
    paper, reduced = _paper_qd(summary.group)
    if paper is None or reduced or not _paper_budget(summary.group, summary.evaluations):
        return "—"
    (p_mean, p_se), ours = paper[0], summary.final["qd_score"]
    own_se = ours[1] if len(summary.runs) > 1 else p_se * math.sqrt(5)
    se = math.hypot(own_se, p_se)
    if se <= 0:
        return "—"
    gap = (ours[0] - p_mean) / se
    if abs(gap) <= QD_SE_BOUND:
        return "within"
    return f"differs: QD-score {ours[0] - p_mean:+,.0f} ({gap:+.1f} s.e.)"


def _figures(values: dict[str, tuple[float, float]], runs: int) -> str:
    """QD-score and coverage as two table cells: mean ± s.e., or the figure alone for one run
    (a single run has no standard error)."""
    q, c = values["qd_score"], values["coverage"]
    if runs > 1:
        return f"{q[0]:,.2f} ± {q[1]:,.2f} | {c[0]:.3f} ± {c[1]:.3f}"
    return f"{q[0]:,.2f} | {c[0]:.3f}"


def table_markdown(summaries: Sequence[GroupSummary]) -> str:
    """The paper's appendix table: domain, algorithm, runs, evaluations, QD-score, coverage,
    and the paper's figures for the same domain and algorithm (— where it has none;
    :func:`paper_row`). A single run has no standard error: its figures stand alone."""
    lines = [
        "| Domain | Algorithm | Runs (seeds) | Evaluations | QD-score | Archive coverage "
        "| Paper: QD-score / coverage (5 runs) | Against the paper (QD-score, issue 55's 2 s.e.) |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for s in summaries:
        seeds = ",".join(str(r.seed) for r in sorted(s.runs, key=lambda r: r.seed))
        ours = _figures(s.final, len(s.runs))
        lines.append(
            f"| {s.group[0]} | {s.group[1]} | {len(s.runs)} ({seeds}) | {s.evaluations:,.0f} "
            f"| {ours} | {paper_row(s.group, s.evaluations)} | {qd_against_paper(s)} |"
        )
    return "\n".join(lines) + "\n"


def equal_budget_markdown(summaries: Sequence[GroupSummary]) -> str:
    """Where a domain's arms ran different budgets (a reduced DSAGE of 5,000 evaluations beside
    searches of 100,000), every arm of that domain at the smallest one: what its archive held
    after its last iteration with at most that many evaluations, mean ± s.e. over its runs,
    best first. Final figures at different budgets do not rank algorithms; these do. "" where
    every domain's arms ran the same budget (within 1 %)."""
    sections = []
    for domain in sorted({s.group[0] for s in summaries}):
        arms = [s for s in summaries if s.group[0] == domain]
        budget = min(s.evaluations for s in arms)
        if all(s.evaluations <= 1.01 * budget for s in arms):
            continue
        rows = []
        for s in arms:
            at = {
                m: mean_se([float(step_values(r, m, np.asarray([budget]))[0]) for r in s.runs])
                for m in METRICS
            }
            rows.append((at["qd_score"][0], s, at))
        lines = [
            f"### {domain} at {budget:,.0f} evaluations",
            "",
            "| Algorithm | Runs | Its own budget | QD-score | Archive coverage |",
            "|---|---|---|---|---|",
        ]
        for _, s, at in sorted(rows, key=lambda row: -row[0]):
            ours = _figures(at, len(s.runs))
            lines.append(f"| {s.group[1]} | {len(s.runs)} | {s.evaluations:,.0f} | {ours} |")
        sections.append("\n".join(lines))
    if not sections:
        return ""
    return (
        "\n## At equal budget\n\nArms of a domain ran different budgets; here each at the smallest "
        "(its archive after its last iteration with at most that many evaluations; mean ± s.e. over "
        "its runs).\n\n" + "\n\n".join(sections) + "\n"
    )


def write_csv(path: Path, summaries: Sequence[GroupSummary]) -> None:
    with path.open("w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(
            [
                "domain",
                "algorithm",
                "runs",
                "evaluations",
                "qd_score",
                "qd_score_se",
                "coverage",
                "coverage_se",
            ]
        )
        for s in summaries:
            q, c = s.final["qd_score"], s.final["coverage"]
            w.writerow([s.group[0], s.group[1], len(s.runs), s.evaluations, q[0], q[1], c[0], c[1]])


def plot_curves(path: Path, summaries: Sequence[GroupSummary], points: int = 200) -> None:
    """QD-score and coverage over evaluations per domain: mean and 95 % interval per algorithm."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from nca_qd.viz import save_figure

    domains = sorted({s.group[0] for s in summaries})
    fig, axes = plt.subplots(len(domains), 2, figsize=(10, 3.4 * len(domains)), squeeze=False)
    for row, domain in zip(axes, domains):
        for s in (s for s in summaries if s.group[0] == domain):
            grid = np.linspace(0, s.evaluations, points)
            for ax, metric in zip(row, METRICS):
                v = np.stack([step_values(r, metric, grid) for r in s.runs])
                with warnings.catch_warnings():  # grid points before any run's first iteration
                    warnings.simplefilter("ignore", RuntimeWarning)
                    mean = np.nanmean(v, axis=0)
                    se = np.nanstd(v, axis=0, ddof=1) / np.sqrt(np.maximum(np.sum(np.isfinite(v), axis=0), 1))
                line = ax.plot(grid, mean, label=f"{s.group[1]} (n={len(s.runs)})")[0]
                if len(s.runs) > 1:
                    n = np.sum(np.isfinite(v), axis=0)
                    half = np.asarray([_t95(int(k)) if k > 1 else np.nan for k in n]) * se
                    low = np.maximum(mean - half, 0.0)  # both metrics are non-negative
                    ax.fill_between(grid, low, mean + half, alpha=0.2, color=line.get_color())
        for ax, metric in zip(row, METRICS):
            ax.set_title(f"{domain}: {metric.replace('_', '-')}", fontsize=9)
            ax.set_xlabel("evaluations")
            ax.grid(alpha=0.3)
        row[0].legend(fontsize=8)
    save_figure(fig, path)


def compare(paths: Iterable[str | Path], out: str | Path, name: str = "comparison") -> tuple[str, list[Path]]:
    """Aggregate the runs at ``paths`` into ``out``: ``<name>.md``, ``<name>.csv`` and
    ``<name>.png``; where runs measure environment entropy, their elites at low entropy (the
    paper's appendix on α, :mod:`nca_qd.compare_archive`); where runs hold an evaluation, the
    paper's tables 2, 3 and 5 too
    (:mod:`nca_qd.compare_evaluation`, ``<name>_evaluation.csv``) and, where it has curves over
    agent counts, figure 3 with its exact points (:mod:`nca_qd.compare_curves`,
    ``<name>_agents.png``); where check folders of the runs lie below ``paths`` (the archives'
    best at S_eval, screened or exact, and the two-stage pick), their tables
    (:mod:`nca_qd.compare_top`). Returns the Markdown and the files written."""
    if not name or Path(name).name != name or name.startswith("."):
        raise NcaQdError(f"name must be a plain file name stem (no folders), got {name!r}")
    paths = list(paths)
    curves, waiting = read_runs(paths)
    summaries = summarise(curves)
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    table = table_markdown(summaries) + equal_budget_markdown(summaries)
    if waiting:
        table += (
            "\nNot in these tables yet (no iteration finished): "
            + ", ".join(f"`{w}`" for w in waiting)
            + ".\n"
        )
    from nca_qd.compare_archive import profiles_markdown, read_profiles
    from nca_qd.compare_curves import curves_markdown, read_curves
    from nca_qd.compare_curves import plot_curves as plot_agent_curves
    from nca_qd.compare_evaluation import (
        read_arms,
        read_variants,
        tables_markdown,
        variants_markdown,
        write_scaling_csv,
    )
    from nca_qd.compare_top import find_checks, top_markdown
    from nca_qd.io import atomic_write_text

    files = [out / f"{name}.md", out / f"{name}.csv", out / f"{name}.png"]
    runs = [(c.path, c.group[1], c.seed) for c in curves]
    arms = read_arms(runs)
    variants = read_variants(runs)
    table += tables_markdown(arms) + variants_markdown(variants, arms)
    table += profiles_markdown(read_profiles([(c.path, *c.group, c.seed) for c in curves]))
    agent_curves = read_curves(runs)
    table += curves_markdown(agent_curves, f"{name}_agents.png")
    table += top_markdown(find_checks(paths, runs), out)
    atomic_write_text(files[0], table)
    write_csv(files[1], summaries)
    plot_curves(files[2], summaries)
    if arms or variants:
        files.append(out / f"{name}_evaluation.csv")
        write_scaling_csv(files[-1], arms, variants)
    if agent_curves:
        files.append(out / f"{name}_agents.png")
        plot_agent_curves(files[-1], agent_curves)
    return table, files
