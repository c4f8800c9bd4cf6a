"""Emitters: where each batch of solutions comes from, and how they learn from the archive.

As in pyribs, emitters are separate from archives; here they are functional (state in, state
out) so that a whole ask or tell is one jitted call. All emitters share one interface:

* ``init(key) -> state``
* ``ask(state, archive, key) -> (solutions [batch, d], state)``
* ``tell(state, archive, solutions, objective, add_info, key) -> state``

:class:`ESEmitters` runs ``n`` CMA-ES instances (evosax) side by side: ranked by improvement
over the optimisation archive's thresholds it is CMA-MAE's emitter (pyribs'
``EvolutionStrategyEmitter`` with ``ranker="imp"``, ``selection_rule="mu"``,
``restart_rule="no_improvement"``); ranked by objective with the basic restart rule it is the
plain CMA-ES baseline. :class:`IsoLineEmitter` is MAP-Elites with QDax's Iso+LineDD operator.

Known hazard (jaxlib 0.10 on a 2-core CPU): one jitted program holding two independent batched
linear-algebra calls (a vmapped ``eigh`` beside a vmapped ``cholesky``) can freeze forever. The
emitters are therefore iterated with ``lax.map`` (sequential), never ``vmap``-ed; sampling
uses the cached eigenbasis, so no ``cholesky`` appears at all, and the ``eigh`` runs on the host
(see :func:`eigen_decomposition`).
"""

from __future__ import annotations

import math
from typing import Any

import chex
import flax.struct
import jax
import jax.numpy as jnp
import numpy as np
from evosax.algorithms.distribution_based.cma_es import CMA_ES
from qdax.core.emitters.mutation_operators import isoline_variation

from nca_qd.host_blas import one_thread
from nca_qd.qd.archive import AddInfo, ThresholdRepertoire


def _host_eigh(c: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    # One BLAS thread, always: with more, OpenBLAS's eigenvectors change with the thread count
    # (nca_qd.host_blas), and multi-threaded it also spin-waits (4x slower at 100x100, 8 ms
    # against 2 ms, whenever the other core was busy, e.g. with XLA).
    with one_thread():
        d_sq, b = np.linalg.eigh(np.asarray(c))
    return d_sq.astype(np.float32), b.astype(np.float32)


def eigen_decomposition(C: jax.Array) -> tuple[jax.Array, jax.Array, jax.Array]:
    """evosax's eigendecomposition step (symmetrise, clip, diagonal loading, ``C = B D^2 B^T``)
    with the ``eigh`` itself done by numpy's LAPACK on the host.

    Why not ``jnp.linalg.eigh``: on jaxlib 0.10's CPU backend it measured 40-110 ms for a
    100x100 matrix against 0.8 ms for numpy (and no faster at 1,730x1,730), which made the
    sphere benchmark's 15 emitters spend most of their time here.
    """
    C = (C + C.T) / 2
    diag = jnp.diag_indices_from(C)
    C = C.at[diag].set(jnp.maximum(C[diag], 0.0))
    C = jnp.minimum(C, 1e8) + 1e-8 * jnp.eye(C.shape[0], dtype=C.dtype)
    shapes = (jax.ShapeDtypeStruct(C.shape[:1], jnp.float32), jax.ShapeDtypeStruct(C.shape, jnp.float32))
    d_sq, B = jax.pure_callback(_host_eigh, shapes, C, vmap_method="sequential")
    return C, B, jnp.sqrt(jnp.maximum(d_sq, 1e-8))


class LazyCMAES(CMA_ES):
    """evosax's CMA-ES with a lazy eigendecomposition.

    evosax recomputes ``eigh(C)`` at every ``ask``: at d ~ 2,000 that dominates a QD iteration.
    Like pyribs' CMA-ES (the implementation the CMA-MAE paper used), the eigenbasis is refreshed
    only every ``max(1, floor(0.5 / (d (c1 + c_mu))))`` generations and sampling uses the cached
    one in between.
    Positive recombination weights over the best half only (pyribs' ``truncation`` rule).
    """

    def __init__(self, population_size: int, num_dims: int):
        super().__init__(population_size, jnp.zeros(num_dims))
        self.use_negative_weights = False
        p = self._default_params
        self.eigen_gap = max(1, int(math.floor(0.5 / (num_dims * float(p.c_1 + p.c_mu)))))

    def _ask(self, key, state, params):
        refresh = state.generation_counter % self.eigen_gap == 0
        C, B, D = jax.lax.cond(refresh, eigen_decomposition, lambda c: (c, state.B, state.D), state.C)
        z = jax.random.normal(key, (self.population_size, self.num_dims))
        population = state.mean + state.std * ((z * D) @ B.T)
        return population, state.replace(C=C, B=B, D=D)

    def should_stop(self, state, ranking_values: jax.Array) -> jax.Array:
        """pyribs' CMA-ES stop test: ill-conditioned, collapsed, or flat ranking values."""
        cond = (jnp.max(state.D) / jnp.min(state.D)) ** 2 > 1e14
        area = state.std * jnp.max(state.D) < 1e-11
        flat = jnp.abs(jnp.max(ranking_values) - jnp.min(ranking_values)) < 1e-12
        return cond | area | flat | jnp.any(jnp.isnan(state.mean))


class ESEmitterState(flax.struct.PyTreeNode):
    es: Any  # evosax CMA-ES state, stacked over emitters
    restarts: jax.Array  # [n] restarts so far, per emitter


def sample_elites(archive: ThresholdRepertoire, key: jax.Array, n: int) -> jax.Array:
    """``n`` genotypes drawn uniformly (with replacement) from the archive's occupied cells."""
    occ = archive.occupied
    p = occ / jnp.maximum(jnp.sum(occ), 1)
    idx = jax.random.choice(key, occ.shape[0], (n,), p=p)
    return archive.genotypes[idx]


class ESEmitters:
    """``n_emitters`` CMA-ES emitters of ``batch_size`` each (see module docstring)."""

    def __init__(
        self,
        n_emitters: int,
        batch_size: int,
        dim: int,
        sigma0: float,
        ranking: str = "improvement",
        restart_rule: str = "no_improvement",
    ):
        if ranking not in ("improvement", "objective"):
            raise ValueError(f"unknown ranking {ranking!r}")
        if restart_rule not in ("no_improvement", "basic"):
            raise ValueError(f"unknown restart rule {restart_rule!r}")
        self.n_emitters, self.emitter_batch, self.dim = n_emitters, batch_size, dim
        self.batch_size = n_emitters * batch_size
        self.sigma0, self.ranking, self.restart_rule = sigma0, ranking, restart_rule
        self.es = LazyCMAES(batch_size, dim)
        self.params = self.es.default_params.replace(std_init=jnp.asarray(sigma0, jnp.float32))

    def _fresh(self, key: jax.Array, mean: jax.Array):
        return self.es.init(key, mean, self.params)

    def init(self, key: jax.Array) -> ESEmitterState:
        keys = jax.random.split(key, self.n_emitters)
        es = jax.lax.map(lambda k: self._fresh(k, jnp.zeros(self.dim)), keys)
        return ESEmitterState(es=es, restarts=jnp.zeros(self.n_emitters, jnp.int32))

    def ask(self, state: ESEmitterState, archive: ThresholdRepertoire, key: jax.Array):
        keys = jax.random.split(key, self.n_emitters)
        pop, es = jax.lax.map(lambda a: self.es.ask(a[0], a[1], self.params), (keys, state.es))
        return pop.reshape(self.batch_size, self.dim), state.replace(es=es)

    def tell(
        self,
        state: ESEmitterState,
        archive: ThresholdRepertoire,
        solutions: jax.Array,
        objective: jax.Array,
        add_info: AddInfo,
        key: jax.Array,
    ) -> ESEmitterState:
        chex.assert_shape(solutions, (self.batch_size, self.dim))
        n, b = self.n_emitters, self.emitter_batch
        values = add_info.value if self.ranking == "improvement" else objective
        values = jnp.where(jnp.isfinite(values), values, -1e30).reshape(n, b)
        added = (add_info.status > 0).reshape(n, b)
        restart_means = sample_elites(archive, key, n)
        has_elites = jnp.any(archive.occupied)
        keys = jax.random.split(jax.random.fold_in(key, 1), n)

        def one(args):
            es_state, pop, val, add, mean0, k = args
            # evosax minimises: hand it the negated ranking values.
            new = self.es.tell(k, pop, -val, es_state, self.params)[0]
            stop = self.es.should_stop(new, val)
            if self.restart_rule == "no_improvement":
                stop = stop | ~jnp.any(add)
            mean = jnp.where(has_elites, mean0, jnp.zeros(self.dim))
            fresh = self._fresh(k, mean)
            return jax.tree.map(lambda a, c: jnp.where(stop, a, c), fresh, new), stop

        es, restarted = jax.lax.map(
            one, (state.es, solutions.reshape(n, b, self.dim), values, added, restart_means, keys)
        )
        return state.replace(es=es, restarts=state.restarts + restarted.astype(jnp.int32))

    # --- checkpoints (nca_qd.qd.checkpoint) -------------------------------------------------
    def compact_state(
        self, state: ESEmitterState, rank: int, tolerance: float
    ) -> tuple[dict[str, np.ndarray], dict]:
        """The emitters' state without its ``d x d`` arrays where that loses (almost) nothing.

        Every vector and counter is stored exactly. Two matrices per emitter are stored
        compactly (:func:`compact_matrices`): the covariance ``C`` and the one CMA-ES samples
        with, ``B D^2 B^T`` -- the covariance at the last (lazy) eigendecomposition, which at
        d ~ 2,000 is refreshed only every ~230 generations, so between refreshes the search
        samples from an older, rounder distribution than ``C``. Restoring ``B`` and ``D`` from
        that matrix rather than from ``C`` keeps the resumed search sampling as the
        uninterrupted one would. Returns the arrays and, per emitter, what was left out."""
        es = state.es
        out = {
            k: np.asarray(v)
            for k, v in {
                ".restarts": state.restarts,
                ".es.mean": es.mean,
                ".es.std": es.std,
                ".es.p_std": es.p_std,
                ".es.p_c": es.p_c,
                ".es.generation_counter": es.generation_counter,
                ".es.best_solution": es.best_solution,
                ".es.best_fitness": es.best_fitness,
            }.items()
        }
        with one_thread():  # what a resumed run reads: the same bits on any machine
            C = np.asarray(es.C)
            arrays, left, full = compact_matrices(C, rank, tolerance)
            out.update({".es.C" + k: v for k, v in arrays.items()})
            B, D = np.asarray(es.B, np.float32), np.asarray(es.D, np.float32)
            scalar = np.ptp(D, axis=1) <= 1e-7 * np.abs(D).mean(axis=1)
            sampling = np.stack(
                [
                    np.diag(np.full(self.dim, d_[0] ** 2)) if sc else (b * d_**2) @ b.T
                    for b, d_, sc in zip(B, D, scalar)
                ]
            ).astype(np.float32)
            arrays, s_left, s_full = compact_matrices(sampling, rank, tolerance)
        out.update({".es.S" + k: v for k, v in arrays.items()})
        return out, {
            "covariance_left_out": left,
            "covariance_full": full,
            "sampling_left_out": s_left,
            "sampling_full": s_full,
        }

    def expand_state(self, arrays: dict[str, np.ndarray], template: ESEmitterState) -> ESEmitterState:
        """Inverse of :meth:`compact_state`; ``B`` and ``D`` come from the sampling matrix."""
        from nca_qd.errors import NcaQdError

        n, d = self.n_emitters, self.dim
        C = expand_matrices({k[len(".es.C") :]: v for k, v in arrays.items() if k.startswith(".es.C")}, n, d)
        S = expand_matrices({k[len(".es.S") :]: v for k, v in arrays.items() if k.startswith(".es.S")}, n, d)
        B, D = [], []
        for s_ in S:
            if not (s_ - np.diag(np.diag(s_))).any() and np.ptp(np.diag(s_)) == 0:
                # A multiple of I (the basis of a fresh start): eigh would return I as well.
                B.append(np.eye(d, dtype=np.float32))
                D.append(np.full(d, np.sqrt(s_[0, 0]), np.float32))
                continue
            d_sq, b = _host_eigh((s_ + s_.T) / 2)
            B.append(b)
            D.append(np.sqrt(np.maximum(d_sq, 1e-8)))
        es = template.es
        fields = {
            "mean": ".es.mean",
            "std": ".es.std",
            "p_std": ".es.p_std",
            "p_c": ".es.p_c",
            "generation_counter": ".es.generation_counter",
            "best_solution": ".es.best_solution",
            "best_fitness": ".es.best_fitness",
        }
        values = {}
        for field, name in fields.items():
            ref = getattr(es, field)
            if name not in arrays or arrays[name].shape != ref.shape:
                raise NcaQdError(f"emitter state's {field} does not match this configuration")
            values[field] = jnp.asarray(arrays[name], dtype=ref.dtype)
        es = es.replace(**values, C=jnp.asarray(C), B=jnp.asarray(np.stack(B)), D=jnp.asarray(np.stack(D)))
        restarts = jnp.asarray(arrays[".restarts"], dtype=template.restarts.dtype)
        return template.replace(es=es, restarts=restarts)


def compact_matrices(
    M: np.ndarray, rank: int, tolerance: float
) -> tuple[dict[str, np.ndarray], list[float], list[bool]]:
    """Symmetric matrices ``[n, d, d]`` as diagonal + ``rank`` eigenpairs of the off-diagonal
    part (:func:`lowrank_offdiagonal`) where that leaves out at most ``tolerance``, in full
    otherwise. Returns the arrays, what was left out per matrix and which were kept in full."""
    parts = [lowrank_offdiagonal(np.asarray(m, np.float64), rank) for m in M]
    full = np.array([p[3] > tolerance for p in parts], bool)
    arrays = {
        "_diag": np.stack([p[0] for p in parts]).astype(np.float32),
        "_vectors": np.stack([p[1] for p in parts]).astype(np.float32),
        "_values": np.stack([p[2] for p in parts]).astype(np.float32),
        "_full_index": np.flatnonzero(full).astype(np.int32),
        "_full": np.asarray(M, np.float32)[full],
    }
    return arrays, [0.0 if f else float(p[3]) for p, f in zip(parts, full)], full.tolist()


def expand_matrices(arrays: dict[str, np.ndarray], n: int, d: int) -> np.ndarray:
    """Inverse of :func:`compact_matrices` (float32 ``[n, d, d]``)."""
    from nca_qd.errors import NcaQdError

    try:
        diag, vec, val = arrays["_diag"], arrays["_vectors"], arrays["_values"]
        full_index, full = arrays["_full_index"], arrays["_full"]
    except KeyError as exc:
        raise NcaQdError(f"emitter state lacks {exc} (written by another algorithm)") from None
    if diag.shape != (n, d) or vec.shape[:2] != (n, d):
        raise NcaQdError(
            f"emitter state holds {diag.shape[0]} emitters of dimension "
            f"{diag.shape[-1]}; this configuration has {n} of {d}"
        )
    M = np.einsum("edk,ek,efk->edf", vec.astype(np.float64), val.astype(np.float64), vec.astype(np.float64))
    M[:, np.arange(d), np.arange(d)] = diag
    M = M.astype(np.float32)
    M[full_index] = full
    return M


def lowrank_offdiagonal(
    C: np.ndarray, rank: int, seed: int = 0
) -> tuple[np.ndarray, np.ndarray, np.ndarray, float]:
    """``C`` (symmetric) as ``diag(C) + V diag(w) V^T`` with the ``rank`` eigenpairs of the
    off-diagonal part largest in magnitude (randomised subspace iteration: O(d^2 rank), no full
    ``eigh``). Returns (diagonal, V [d, rank], w [rank], left out) where "left out" is
    ``||C - approximation||_F / mean(diag C)``: for a covariance near ``s I`` the KL divergence
    between the two Gaussians is about a quarter of its square."""
    d = C.shape[0]
    diag = np.diag(C).copy()
    off = C - np.diag(diag)
    scale = max(float(np.mean(diag)), 1e-300)
    k = min(rank, d)
    if k == 0 or not off.any():
        return diag, np.zeros((d, k)), np.zeros(k), float(np.linalg.norm(off)) / scale
    rng = np.random.default_rng(seed)
    Q, _ = np.linalg.qr(rng.standard_normal((d, min(d, k + 8))))
    for _ in range(4):
        Q, _ = np.linalg.qr(off @ Q)
    w, V = np.linalg.eigh(Q.T @ off @ Q)
    top = np.argsort(-np.abs(w))[:k]
    w, V = w[top], Q @ V[:, top]
    left = float(np.linalg.norm(off - (V * w) @ V.T))
    return diag, V, w, left / scale


class IsoLineState(flax.struct.PyTreeNode):
    asked: jax.Array  # solutions emitted so far


class IsoLineEmitter:
    """MAP-Elites: parents drawn uniformly from the archive, QDax's Iso+LineDD variation.

    Until ``n_initial`` solutions have been emitted (and always while the archive is empty),
    solutions are drawn from N(0, initial_sigma^2 I) instead: with ``n_initial = 0`` and
    ``initial_sigma = iso_sigma`` this is pyribs' ``IsoLineEmitter`` with ``x0 = 0``, as the
    paper's code ran it.
    """

    def __init__(
        self,
        batch_size: int,
        dim: int,
        initial_sigma: float,
        iso_sigma: float,
        line_sigma: float,
        n_initial: int,
    ):
        self.batch_size, self.dim, self.initial_sigma = batch_size, dim, initial_sigma
        self.iso_sigma, self.line_sigma, self.n_initial = iso_sigma, line_sigma, n_initial

    def init(self, key: jax.Array) -> IsoLineState:
        return IsoLineState(asked=jnp.zeros((), jnp.int32))

    def ask(self, state: IsoLineState, archive: ThresholdRepertoire, key: jax.Array):
        k1, k2, k3, k4 = jax.random.split(key, 4)
        x1 = sample_elites(archive, k1, self.batch_size)
        x2 = sample_elites(archive, k2, self.batch_size)
        varied = isoline_variation(x1, x2, k3, self.iso_sigma, self.line_sigma)
        random = self.initial_sigma * jax.random.normal(k4, (self.batch_size, self.dim))
        use_random = (state.asked < self.n_initial) | ~jnp.any(archive.occupied)
        sol = jnp.where(use_random, random, varied)
        return sol, state.replace(asked=state.asked + self.batch_size)

    def tell(self, state, archive, solutions, objective, add_info, key):
        return state
