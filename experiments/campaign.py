"""A campaign of searches (the arms of a comparison), run one after another in legs.

    python -m experiments.campaign plan=warehouse_even_qd leg_seconds=7000
    python -m experiments.campaign plan=warehouse_even_qd status=true

The plan (``experiments/conf/campaign/<plan>.yaml`` or a path) names a root folder, overrides
common to every arm and each arm's own; arm ``a`` runs in ``<root>/<a>``. Each call goes on
from where the last stopped: a finished arm is skipped, a started one resumed
(``experiments.run resume=``), the next one started, each with what is left of this call's
``leg_seconds``. Where the plan names ``evaluate: [overrides]``, a finished arm is then
evaluated (``experiments.evaluate run_dir=<root>/<arm> <overrides>``, into
``<root>/<arm>/evaluation``) before the next arm starts: every arm with the same protocol (plus
its own ``evaluate_arms: {arm: [overrides]}``, if any), and the comparison's tables need each
arm's ``evaluation/summary.csv``. The other arms' evaluation records serve an arm's identical
runs (``records_from``: the human baselines are simulated once for the whole comparison). An
arm evaluated before the plan's evaluate overrides changed is evaluated again (its records
serve what did not change). An evaluation cut by the call's time keeps its finished runs
(``evaluation/*.jsonl``) and the next call goes on from them. Where the plan names
``evaluate_also: {tag: [overrides]}``, once every arm has finished and been evaluated, each arm is
evaluated again into ``<root>/<arm>/evaluation_<tag>`` with its evaluate overrides followed by
the tag's (the same protocol with some settings changed: ``experiments.compare`` sets their
S_eval rows beside the main evaluation's), drawing on the main evaluation's records;
``evaluate_also_arms: {tag: [arm, ...]}`` keeps a tag to the arms named (the others skip it: an
evaluation that only some rows of the comparison need costs the others nothing).
Exit 0 when every arm has finished (and been evaluated), 75 when the time ran out first (call
again; commit the arms' folders between calls to carry them to another machine). Bad input: one
line, exit 2.
"""

from __future__ import annotations

import csv
import signal
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any, NamedTuple

from omegaconf import DictConfig, ListConfig, OmegaConf

from experiments.cli import CONF_DIR, compose_config, main_guard
from experiments.evaluate import main as evaluate_main
from experiments.run import EXIT_LEG_ENDED
from experiments.run import main as run_main
from nca_qd.errors import NcaQdError, require_bool

# What Ctrl-C or SIGTERM keeps: a search's last checkpoint, an evaluation's finished runs.
INTERRUPTED = (
    "the running arm's last checkpoint and its evaluation's finished runs are kept; "
    "go on with the same experiments.campaign command"
)

# A search is not started or resumed with less than this left of the call's time (its first
# iteration alone would overrun).
MIN_LEG_S = 60.0


def _overrides(path: Path, what: str, overrides: Any) -> list[str]:
    if not isinstance(overrides, ListConfig) or not all(isinstance(o, str) and "=" in o for o in overrides):
        raise NcaQdError(f"{path}: {what} must be a list of key=value")
    return [str(o) for o in overrides]


def _not_the_campaigns(path: Path, overrides: list[str]) -> list[str]:
    """``overrides`` of an evaluation, refused where they set what the campaign sets."""
    if any(o.startswith(("run_dir=", "out=", "records_from=")) for o in overrides):
        raise NcaQdError(f"{path}: the evaluation's run_dir, out and records_from are the campaign's to set")
    return overrides


class Plan(NamedTuple):
    """A campaign plan, checked: its root folder, the overrides common to every arm, each arm's,
    each arm's evaluate overrides (None: the arms are not evaluated) and the other evaluations
    (``evaluate_also``: tag -> overrides added to each arm's evaluate overrides) and the arms
    each of those is for (``evaluate_also_arms``; every arm where the plan does not say)."""

    root: Path
    common: list[str]
    arms: dict[str, list[str]]
    evaluate: dict[str, list[str]] | None
    also: dict[str, list[str]]
    also_arms: dict[str, list[str]]


TAG_CHARS = set("abcdefghijklmnopqrstuvwxyz0123456789_")


def load_plan(name: str) -> Plan:
    """The plan ``name``, checked. An arm's evaluate overrides are the plan's ``evaluate:``
    followed by its own ``evaluate_arms: {arm: [...]}``, if any (an arm that needs less of the
    protocol: the comparison's curves are the α arms')."""
    path = Path(name) if name.endswith((".yaml", ".yml")) else CONF_DIR / "campaign" / f"{name}.yaml"
    if not path.is_file():
        raise NcaQdError(f"plan={name}: no such plan ({path})")
    raw = OmegaConf.load(path)
    if not isinstance(raw, DictConfig) or not raw.get("root") or not isinstance(raw.get("arms"), DictConfig):
        raise NcaQdError(f"{path}: a plan needs root: <folder> and arms: {{name: [overrides]}}")
    common = list(raw.get("common") or [])
    arms: dict[str, list[str]] = {}
    for arm, overrides in raw.arms.items():
        arms[str(arm)] = _overrides(path, f"arm {arm}'s overrides", overrides)
        if any(o.startswith(("run_dir=", "resume=", "leg_seconds=")) for o in [*common, *arms[str(arm)]]):
            raise NcaQdError(f"{path}: run_dir, resume and leg_seconds are the campaign's to set")
    evaluate = None
    extra = raw.get("evaluate_arms")
    if extra is not None and raw.get("evaluate") is None:
        raise NcaQdError(f"{path}: evaluate_arms adds to evaluate: give evaluate: [overrides] too")
    if extra is not None and (not isinstance(extra, DictConfig) or set(map(str, extra)) - set(arms)):
        raise NcaQdError(f"{path}: evaluate_arms must map arms of the plan to lists of key=value")
    if raw.get("evaluate") is not None:
        shared = _overrides(path, "evaluate", raw.evaluate)
        own = {str(a): _overrides(path, f"evaluate_arms.{a}", o) for a, o in (extra or {}).items()}
        evaluate = {arm: shared + own.get(arm, []) for arm in arms}
        for e in evaluate.values():
            _not_the_campaigns(path, e)
    also_raw = raw.get("evaluate_also")
    also: dict[str, list[str]] = {}
    if also_raw is not None:
        if evaluate is None:
            raise NcaQdError(f"{path}: evaluate_also adds to evaluate: give evaluate: [overrides] too")
        if not isinstance(also_raw, DictConfig):
            raise NcaQdError(f"{path}: evaluate_also must map tags to lists of key=value")
        for tag, overrides in also_raw.items():
            if not str(tag) or set(str(tag)) - TAG_CHARS:
                raise NcaQdError(
                    f"{path}: evaluate_also's tag {tag!r} must be lower-case letters, digits and _"
                )
            also[str(tag)] = _not_the_campaigns(path, _overrides(path, f"evaluate_also.{tag}", overrides))
    also_arms = {tag: list(arms) for tag in also}
    for_arms = raw.get("evaluate_also_arms")
    if for_arms is not None:
        if not isinstance(for_arms, DictConfig) or set(map(str, for_arms)) - set(also):
            raise NcaQdError(f"{path}: evaluate_also_arms must map tags of evaluate_also to lists of arms")
        for tag, named in for_arms.items():
            if not isinstance(named, ListConfig) or not named or set(map(str, named)) - set(arms):
                raise NcaQdError(f"{path}: evaluate_also_arms.{tag} must list arms of the plan")
            also_arms[str(tag)] = [a for a in arms if a in set(map(str, named))]
    return Plan(Path(str(raw.root)), [str(c) for c in common], arms, evaluate, also, also_arms)


def evaluated(run_dir: Path, overrides: list[str] | None = None, folder_name: str = "evaluation") -> bool:
    """Whether an arm's evaluation (in ``<run_dir>/<folder_name>``) has finished (it writes
    summary.csv last) with the plan's ``overrides``: each ``key=value`` as its
    ``evaluate_config.yaml`` holds it. A plan that asks more of its evaluations later (another
    key, another value) thus gets its finished arms evaluated again, from their records where
    the protocol is unchanged."""
    folder = run_dir / folder_name
    if not (folder / "summary.csv").is_file():
        return False
    if not overrides:
        return True
    saved_file = folder / "evaluate_config.yaml"
    if not saved_file.is_file():
        return False
    saved = OmegaConf.to_container(OmegaConf.load(saved_file), resolve=True)
    # a key given twice (the plan's evaluate, then an arm's or a tag's override) holds its last value
    last = dict(o.lstrip("+").partition("=")[::2] for o in overrides)
    for key, value in last.items():
        node: Any = saved
        for part in key.split("."):
            if not isinstance(node, dict) or part not in node:
                return False
            node = node[part]
        wanted = OmegaConf.to_container(OmegaConf.create(f"v: {value}"))["v"]  # the value as YAML reads it
        if node != wanted:
            return False
    return True


class LegEnded(KeyboardInterrupt):
    """The call's time ran out during an evaluation: raised like Ctrl-C, so the evaluation
    stops its runs and keeps the finished ones, as it does on Ctrl-C or SIGTERM."""


@contextmanager
def _deadline(seconds: float | None) -> Iterator[None]:
    """Raise :class:`LegEnded` in the main thread after ``seconds`` (None: never)."""
    if seconds is None:
        yield
        return

    def _ring(signum: int, frame: Any) -> None:
        raise LegEnded

    old = signal.signal(signal.SIGALRM, _ring)
    signal.setitimer(signal.ITIMER_REAL, max(seconds, 0.001))
    try:
        yield
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
        signal.signal(signal.SIGALRM, old)


def _shared_records(run_dir: Path, arms: list[str], folder: str = "evaluation") -> list[str]:
    """``records_from=[...]``: the other ``arms``' evaluation folders (those that exist), whose
    records serve this arm's identical runs: the human baselines are the same layouts at the
    same seeds in every arm, so they are simulated once for the whole comparison. For another
    evaluation (``folder`` other than ``evaluation``) also the arm's own main evaluation, the
    other arms' folders of the same name and every other ``evaluation_*`` folder of the arms
    (one made by hand with some settings changed, e.g. the tiling's repair draws, holds the
    runs of the layouts it shares: a record serves only a run whose every input is the same)."""
    names = ["evaluation"] if folder == "evaluation" else ["evaluation", folder]
    if folder != "evaluation":
        names += sorted(
            {p.name for a in arms for p in (run_dir.parent / a).glob("evaluation_*") if p.is_dir()} - {folder}
        )
    folders = [
        str(run_dir.parent / a / name)
        for name in names
        for a in arms
        if (run_dir.parent / a != run_dir or name != folder) and (run_dir.parent / a / name).is_dir()
    ]
    return [f"records_from=[{','.join(repr(f) for f in folders)}]"] if folders else []


def _evaluate(
    arm: str,
    run_dir: Path,
    overrides: list[str],
    left: float | None,
    arms: list[str] | None = None,
    folder: str = "evaluation",
) -> int:
    """Evaluate a finished arm into ``<run_dir>/<folder>`` within ``left`` seconds (drawing on
    the other ``arms``' records): 0 when done, 75 when cut."""
    print(f"{arm}: evaluating into {folder} ({' '.join(overrides) or 'the defaults'})", flush=True)
    out = [] if folder == "evaluation" else [f"out={run_dir / folder}"]
    try:
        with _deadline(left):
            code = evaluate_main(
                [f"run_dir={run_dir}", *overrides, *out, *_shared_records(run_dir, arms or [], folder)]
            )
    except LegEnded:
        print(f"{arm}: evaluation cut by this call's time; its finished runs are kept", flush=True)
        return EXIT_LEG_ENDED
    return code


def progress(run_dir: Path) -> dict[str, Any]:
    """An arm's state from its folder: not started, started (evaluations so far), finished."""
    metrics, config = run_dir / "metrics.csv", run_dir / "config.yaml"
    if not config.is_file():
        return {"state": "not started", "evaluations": 0}
    cfg = OmegaConf.load(config)
    n_evals = int(cfg.qd.n_evals)
    rows: list[dict[str, str]] = []
    if metrics.is_file():
        with metrics.open() as fh:
            rows = list(csv.DictReader(fh))
    last = rows[-1] if rows else {}
    done = int(float(last.get("evaluations", 0) or 0))
    return {
        "state": "finished" if done >= n_evals else "started",
        "evaluations": done,
        "n_evals": n_evals,
        "qd_score": float(last["qd_score"]) if last else None,
        "coverage": float(last["coverage"]) if last else None,
    }


def _status_line(arm: str, p: dict[str, Any]) -> str:
    if p["state"] == "not started":
        return f"{arm}: not started"
    line = f"{arm}: {p['state']}, {p['evaluations']:,} of {p['n_evals']:,} evaluations"
    if p.get("qd_score") is not None:
        line += f", QD-score {p['qd_score']:,.0f}, coverage {p['coverage']:.3f}"
    return line


def main(argv: list[str]) -> int:
    cfg = compose_config("campaign", argv)
    if not cfg.plan:
        raise NcaQdError("give plan=<name in experiments/conf/campaign> or plan=<file.yaml>")
    budget = cfg.leg_seconds
    if budget is not None and (
        isinstance(budget, bool) or not isinstance(budget, (int, float)) or budget <= 0
    ):
        raise NcaQdError(f"leg_seconds must be a positive number of seconds or null, got {budget!r}")
    plan = load_plan(str(cfg.plan))
    root, common, arms, evaluate = plan.root, plan.common, plan.arms, plan.evaluate
    if require_bool("status", cfg.status):
        for arm in arms:
            line = _status_line(arm, progress(root / arm))
            if evaluate is not None and progress(root / arm)["state"] == "finished":
                if evaluated(root / arm, evaluate[arm]):
                    line += ", evaluated"
                elif evaluated(root / arm):
                    line += ", evaluated, not yet with the plan's evaluate settings (next call)"
                else:
                    line += ", not yet evaluated"
                for tag, extra in plan.also.items():
                    if arm not in plan.also_arms[tag]:
                        continue
                    done = evaluated(root / arm, [*evaluate[arm], *extra], f"evaluation_{tag}")
                    line += f"; evaluation_{tag} {'done' if done else 'after every arm'}"
            print(line)
        return 0
    end = None if budget is None else time.monotonic() + float(budget)
    for arm, overrides in arms.items():
        run_dir = root / arm
        state = progress(run_dir)
        to_evaluate = evaluate is not None and not evaluated(run_dir, evaluate[arm])
        if state["state"] == "finished" and not to_evaluate:
            continue
        left = None if end is None else end - time.monotonic()
        if left is not None and left < MIN_LEG_S:
            print(f"{arm}: left for the next call (this call's leg_seconds are used)")
            return EXIT_LEG_ENDED
        if state["state"] == "finished":
            assert evaluate is not None
            code = _evaluate(arm, run_dir, evaluate[arm], left, list(arms))
            if code != 0:
                return code
            continue
        leg = [] if left is None else [f"leg_seconds={max(left, 1.0):.1f}"]
        print(f"{arm}: {'resuming' if state['state'] == 'started' else 'starting'} in {run_dir}", flush=True)
        if state["state"] == "started":
            code = run_main([f"resume={run_dir}", *leg])
        else:
            code = run_main([*common, *overrides, f"run_dir={run_dir}", *leg])
        if code == EXIT_LEG_ENDED:
            print(f"{arm}: leg ended; go on with: python -m experiments.campaign plan={cfg.plan}")
            return EXIT_LEG_ENDED
        if code != 0:
            return code
        if evaluate is not None:
            left = None if end is None else end - time.monotonic()
            if left is not None and left < MIN_LEG_S:
                print(f"{arm}: its evaluation is left for the next call")
                return EXIT_LEG_ENDED
            code = _evaluate(arm, run_dir, evaluate[arm], left, list(arms))
            if code != 0:
                return code
    for tag, extra in plan.also.items():
        assert evaluate is not None
        folder = f"evaluation_{tag}"
        for arm in plan.also_arms[tag]:
            overrides = [*evaluate[arm], *extra]
            if evaluated(root / arm, overrides, folder):
                continue
            left = None if end is None else end - time.monotonic()
            if left is not None and left < MIN_LEG_S:
                print(f"{arm}: its {folder} is left for the next call")
                return EXIT_LEG_ENDED
            code = _evaluate(arm, root / arm, overrides, left, list(arms), folder)
            if code != 0:
                return code
    print(f"every arm of {cfg.plan} has finished" + (" and been evaluated" if evaluate is not None else ""))
    return 0


if __name__ == "__main__":
    main_guard(main, INTERRUPTED)()
