"""CONTRIBUTING's recipe, exercised: a fourth multi-agent domain is one module (a LayoutKind),
one registry line and one config, and the whole pipeline takes it — generation, repair (checked
by the independent validator), measures, exact RHCR (checked by the independent path checker)
and the QD scorer — with no edit anywhere else.

The toy is a parcel-sorting floor: the NCA generates a storage area of shelves ``@`` and
endpoints ``e``; a fixed column of chutes ``c`` runs down its left side; robots alternate
between an endpoint and a chute.
"""

from __future__ import annotations

import numpy as np
import pytest
from omegaconf import OmegaConf

from nca_qd.layouts import LAYOUTS
from nca_qd.layouts.base import Construction, GoalKind, LayoutKind, TaskModel
from nca_qd.layouts.rules import AdjacencyRule, CountRule, Rules

EMPTY, SHELF, ENDPOINT, CHUTE = range(4)


# ----------------------------------------------------------------- the one new module
class SortingFloor(LayoutKind):
    name = "toy_sorting"
    family = "toy_sorting"
    tiles = ".@ec"
    gen_tiles = ".@e"
    palette = {".": "white", "@": "black", "e": "#3b6fd6", "c": "#ff7f0e"}
    task = TaskModel(blocked="@", goals=(GoalKind("endpoint", "e"), GoalKind("chute", "c")))
    construction = Construction(anchors=(SHELF,), endpoint=ENDPOINT, empty=EMPTY, exact_count=True)
    seed_block = ("e", "@", "e")
    seed_offsets: dict = {}
    eval_agent_step = 5
    frame_cols = 1  # one fixed column each side: chutes on the left, an aisle on the right

    def frame(self, shape):
        fixed = np.zeros(shape, dtype=bool)
        fixed[:, [0, -1]] = True
        lay = np.full(shape, EMPTY, dtype=np.int32)
        lay[1:-1:2, 0] = CHUTE
        return fixed, lay

    def assemble(self, region):
        region = np.asarray(region)
        _, lay = self.frame(self.full_shape(region.shape[-2:]))
        out = np.broadcast_to(lay, region.shape[:-2] + lay.shape).copy()
        out[..., :, 1:-1] = region
        return out

    def rules(self, shape, *, n_shelves=None, n_agents=200):
        fixed, lay = self.frame(shape)
        return Rules(
            tiles=self.tiles,
            passable=frozenset({EMPTY, ENDPOINT}),
            reach_only=frozenset({CHUTE}),
            free_tiles=(EMPTY, SHELF, ENDPOINT),
            adjacency=(
                AdjacencyRule(frozenset({SHELF}), frozenset({ENDPOINT}), "bare shelf"),
                AdjacencyRule(frozenset({ENDPOINT}), frozenset({SHELF}), "bare endpoint"),
            ),
            counts=(CountRule(frozenset({SHELF}), "==", int(n_shelves or 6), "shelves"),),
            fixed=fixed,
            fixed_layout=lay,
        )

    def measures(self, layouts):
        layouts = np.asarray(layouts)
        shelves = (layouts == SHELF).sum(axis=(-2, -1))
        endpoints = (layouts == ENDPOINT).sum(axis=(-2, -1))
        return np.stack([shelves, endpoints], axis=-1).astype(np.float32)


# ----------------------------------------------------------------- and its config
CONFIG = """
name: toy_sorting
size: {train: [7, 8], eval: [9, 10]}
nca_iters: {train: 10, eval: 20}
measures: {names: [shelves, endpoints], ranges: [[0, 20], [0, 40]], cells: [5, 5]}
objective_range: [0, null]
alpha: 5
simulation: {T: 40, n_runs: 2}
n_agents: {train: 6, eval: 8}
repair: {method: neighbourhood, time_limit_s: 30, improve_windows: 2,
         n_shelves: {train: 6, eval: 8}}
failed_repair_objective: 0.0
"""


@pytest.fixture
def toy(monkeypatch):
    monkeypatch.setitem(LAYOUTS, "toy_sorting", SortingFloor())  # the one registry line
    from nca_qd.domains import make_domain

    return make_domain(OmegaConf.create(CONFIG))


def test_a_new_multi_agent_domain_runs_through_the_whole_pipeline(toy):
    import jax

    from nca_qd.pipeline import generate, make_generator
    from nca_qd.repair import make_rules, repair
    from nca_qd.repair.validator import check
    from nca_qd.scoring.jobs import repair_options
    from nca_qd.sim.checker import check_run
    from nca_qd.sim.rhcr import simulate

    assert toy.name == "toy_sorting" and toy.n_tiles == 3
    gen = make_generator(toy)
    params = 0.3 * jax.random.normal(jax.random.PRNGKey(0), (3, gen.n_params))
    layouts = toy.assemble(generate(toy, gen, params))
    assert layouts.shape == (3, 7, 10) and (layouts[:, 1:-1:2, 0] == CHUTE).all()

    opts = repair_options(toy.cfg, "train")
    for lay in layouts:
        res = repair("toy_sorting", lay, **opts)
        assert res.layout is not None
        assert check(res.layout, make_rules("toy_sorting", lay.shape, n_shelves=6)) is None
        assert toy.measures(res.layout[None])[0, 0] == 6  # exactly N_s shelves
        rows = ["".join(toy.layout_tiles[t] for t in row) for row in res.layout]
        run = simulate(rows, "toy_sorting", 6, 40, seed=1, record_paths=True)
        report = check_run(run, rows)  # collisions, moves, goal kinds, task counts
        assert report.finished_tasks == run.finished_tasks


def test_the_qd_scorer_takes_the_new_domain(toy):
    import jax

    from nca_qd.interfaces import ScoringContext
    from nca_qd.pipeline import make_generator

    gen = make_generator(toy)
    regions = np.asarray(
        gen.generate(
            0.3 * jax.random.normal(jax.random.PRNGKey(1), (4, gen.n_params)),
            toy.seed(toy.gen_shape("train")),
            10,
        )
    )
    run_cfg = {"eval": {"workers": 0, "screen": False, "memo": False}}
    scorer = toy.make_evaluator(run_cfg)
    try:
        batch = scorer(
            regions, jax.random.PRNGKey(0), ScoringContext(result_elite=lambda m: np.full(len(m), -np.inf))
        )
    finally:
        scorer.close()
    assert np.asarray(batch.valid).all() and np.asarray(batch.result_valid).all()
    assert (np.asarray(batch.measures)[:, 0] == 6).all()
    assert (np.asarray(batch.result_objective) >= 0).all()
