"""Re-derive a constant the product uses (``nca_qd.calibration`` says which and how).

    python -m experiments.calibrate fit=crowd_threshold \
        memo=results/warehouse_uneven_a5/eval_memo.npz until=28
    python -m experiments.calibrate fit=crowd_drift \
        memo=results/manufacturing_a5/eval_memo.npz from_iteration=101
    python -m experiments.calibrate fit=screen_skips run_dir=results/manufacturing_a5 n=300 \
        out=results/manufacturing_a5/screen_skips.jsonl replay=[18,22]
    python -m experiments.calibrate fit=congested maps=<folder of the paper's 33x36 maps>

Prints JSON lines. Bad input: one line on stderr, exit status 2.
"""

from __future__ import annotations

import json
from collections.abc import Iterator
from pathlib import Path

from experiments.cli import check_writable, compose_config, main_guard
from nca_qd.errors import NcaQdError, require_bool

FITS = ("crowd_threshold", "crowd_drift", "screen_skips", "congested")


def _file(value, key: str) -> Path:
    if not value:
        raise NcaQdError(f"give {key}=<file>")
    path = Path(str(value))
    if not path.is_file():
        raise NcaQdError(f"{key}={path}: no such file")
    return path


def _int(cfg, key: str, low: int) -> int:
    value = cfg[key]
    if isinstance(value, bool) or not isinstance(value, int) or value < low:
        raise NcaQdError(f"{key} must be an integer >= {low}, got {value!r}")
    return value


def _lines(cfg) -> Iterator[dict]:
    """The chosen fit's lines, its input checked first."""
    if cfg.fit in ("crowd_threshold", "crowd_drift"):
        from nca_qd.calibration import crowding

        memo = _file(cfg.memo, "memo")
        if cfg.fit == "crowd_drift":
            until = 10**9 if cfg.until is None else _int(cfg, "until", 0)
            return crowding.threshold_drift(memo, _int(cfg, "from_iteration", 0), until)
        if cfg.until is None:
            raise NcaQdError("give until=<the last iteration to calibrate on>")
        configured = _configured_threshold(memo)
        limit = None if cfg.limit is None else _int(cfg, "limit", 4)
        return crowding.calibrate_threshold(
            memo, _int(cfg, "until", 0), configured, _int(cfg, "split_seed", 0), limit
        )
    if cfg.fit == "screen_skips":
        from nca_qd.calibration import skips

        if not cfg.run_dir or not (Path(cfg.run_dir) / "eval_memo.npz").is_file():
            raise NcaQdError(f"run_dir={cfg.run_dir}: not a multi-agent run directory with an eval_memo.npz")
        if not cfg.out:
            raise NcaQdError(
                "give out=<a JSON-lines file> (it keeps the checked layouts; a rerun goes on from it)"
            )
        check_writable(cfg.out, "out")
        thresholds = None if cfg.replay is None else _thresholds(cfg.replay)
        n = _int(cfg, "n", 0)
        return skips.check(
            Path(cfg.run_dir),
            n,
            _int(cfg, "seed", 0),
            Path(cfg.out),
            thresholds,
            require_bool("replay_only", cfg.replay_only),
        )
    if cfg.fit == "congested":
        from nca_qd.calibration import congested

        maps = Path(str(cfg.maps)) if cfg.maps else None
        if maps is None or not (maps / "human_33x36.json").is_file():
            raise NcaQdError(
                "give maps=<a folder with the paper's human_33x36.json and paper_cma-mae_a5_even_33x36.json>"
            )
        caches = [None if c is None else Path(str(c)) for c in (cfg.rhcr_cache_fit, cfg.rhcr_cache_check)]
        for c, key in zip(caches, ("rhcr_cache_fit", "rhcr_cache_check")):
            if c is not None:
                check_writable(c, key)
        return iter([congested.refit(maps, caches[0], caches[1], float(cfg.efficiency))])
    raise NcaQdError(f"fit must be one of {', '.join(FITS)}, got {cfg.fit!r}")


def _thresholds(value) -> list[float]:
    items = list(value) if not isinstance(value, (int, float, str)) else [value]
    try:
        out = [float(x) for x in items]
    except (TypeError, ValueError):
        out = []
    if not out or any(not x > 0 for x in out):
        raise NcaQdError(
            f"replay must be a list of positive crowding thresholds, e.g. [18,22], got {value!r}"
        )
    return out


def _configured_threshold(memo: Path) -> float:
    """The crowding threshold the memo's domain uses today (its YAML)."""
    import numpy as np
    from omegaconf import OmegaConf

    from nca_qd.sim.screen import crowd_mean_for

    domain = json.loads(str(np.load(memo)["fingerprint"]))["domain"]
    return crowd_mean_for(OmegaConf.to_container(compose_config("run", [f"domain={domain}"]).domain))


def main(argv: list[str]) -> int:
    cfg = compose_config("calibrate", argv)
    for line in _lines(cfg):
        print(json.dumps(line), flush=True)
    return 0


if __name__ == "__main__":
    main_guard(main)()
