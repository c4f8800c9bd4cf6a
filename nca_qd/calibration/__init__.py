"""The fits behind the constants the product uses, each re-derived by a command
(``python -m experiments.calibrate fit=<fit> ...``; it prints JSON lines).

- ``fit=crowd_threshold memo=<run>/eval_memo.npz until=<iteration>``
  (:mod:`~nca_qd.calibration.crowding`): a domain's crowding threshold
  (``domain.simulation.screen_crowd_mean``), the scaled estimate's factor (``eval.screen_scale``)
  and RHCR's share of free flow where it flows (``eval.screen_efficiency``), fitted on half a
  search's exactly-run layouts, checked on the other half.
- ``fit=crowd_drift memo=... from_iteration=... until=...`` (same module): whether a threshold
  still holds on the layouts a search finds later.
- ``fit=screen_skips run_dir=<run> n=300 out=<run>/screen_skips.jsonl replay=[18,20,22]``
  (:mod:`~nca_qd.calibration.skips`): how often the screen wrongly kept a layout from exact
  runs, and which threshold sends all those to exact runs (the manufacturing and uneven
  thresholds from 2026-11-29).
- ``fit=congested maps=<folder of the paper's 33x36 maps>``
  (:mod:`~nca_qd.calibration.congested`, on the layout set of
  :mod:`~nca_qd.calibration.layout_set`): :data:`nca_qd.sim.free_flow.CONGESTED_MODEL`
  (``eval.screen_congested``).

Benchmarks (``benchmarks/``) time and report; they import these fits, never the other way.
"""
