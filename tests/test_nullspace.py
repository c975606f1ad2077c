"""The null space solvers against their definition, on tensors with a planted solution.

J = Bᵀ B with B's rows orthogonal to three planted parameter vectors p_c (fixed rows
I_sx, I_sy, I_t equal to the unit vectors): then P = p exactly, the model error is 0 to
roundoff, and g, the row factor of the error estimate, is by definition (docstring of
estimator/nullspace.py) the diagonal of (J_qq + δ I)^-1 with J_qq J without the fixed
rows and columns and δ = RIDGE trace J; here it is computed directly with
``numpy.linalg.inv``.  Both the reference (LAPACK) solver and the fast (numba) one.
"""

from __future__ import annotations

import numpy as np

from gridflow.estimator.models import get_model
from gridflow.estimator.nullspace import COMBINED_ROWS, RIDGE, null_space


def _planted(n_pixels=300, seed=0):
    model = get_model("full", 2)
    n, k = model.n, model.null_dim
    fixed = [model.index(r) for r in model.fixed_rows]
    free = [i for i in range(n) if i not in fixed]
    rng = np.random.default_rng(seed)
    P = np.zeros((n_pixels, n, k))
    J = np.empty((n_pixels, n, n))
    for i in range(n_pixels):
        p = np.zeros((n, k))
        p[free] = rng.normal(scale=0.5, size=(len(free), k))
        p[fixed, range(k)] = 1.0
        # rows of B: random vectors projected onto the orthogonal complement of span(p)
        q, _ = np.linalg.qr(p)
        B = rng.normal(size=(3 * n, n))
        B -= (B @ q) @ q.T
        J[i] = B.T @ B
        P[i] = p
    return model, J, P, free


def _packed(J, model):
    """J (N, n, n) as the packed planes (E, N) and their index (n, n) of the fast solver."""
    n = model.n
    iu = np.triu_indices(n)
    index = np.empty((n, n), dtype=np.int64)
    index[iu] = index[iu[1], iu[0]] = np.arange(iu[0].size)
    return np.ascontiguousarray(J[:, iu[0], iu[1]].T), index


def _g_by_definition(J, model, free):
    tr = np.trace(J, axis1=1, axis2=2)
    Jq = J[:, free][:, :, free] + (RIDGE * tr)[:, None, None] * np.eye(len(free))
    g = np.full(J.shape[:2], np.nan)
    g[:, free] = np.diagonal(np.linalg.inv(Jq), axis1=1, axis2=2)
    return g


def test_reference_solver_finds_the_planted_solution():
    """Measured: P within 3.8e-15 of the planted vectors, model error <= 1.7e-16 of
    trace J, g equal to the definition to the last bit (asked: 10x, 4e-14 and 2e-15;
    g within 1e-14 relative)."""
    model, J, P_true, free = _planted()
    ns = null_space(J, model)
    tr = np.trace(J, axis1=1, axis2=2)
    assert ns.valid.all()
    np.testing.assert_allclose(ns.P, P_true, rtol=0, atol=4e-14)
    assert np.all(np.abs(ns.model_error) <= 2e-15 * tr)
    np.testing.assert_allclose(ns.g, _g_by_definition(J, model, free), rtol=1e-14)


def test_fast_solver_finds_the_planted_solution():
    """The numba solver reads J packed (one plane per distinct entry) and fills g only for
    the rows whose two estimates are combined.  Measured (every pixel settled in the
    lanes): P within 1.8e-15, g within 2.0e-15 relative, model error <= 2.7e-17 of
    trace J; asked: 10x."""
    from gridflow.estimator._solver import null_space_packed

    model, J, P_true, free = _planted()
    ns = null_space_packed(*_packed(J, model), model)
    assert ns.valid.all()
    np.testing.assert_allclose(ns.P, P_true, rtol=0, atol=2e-14)
    rows = [model.index(r) for r in COMBINED_ROWS if r in model.rows]
    np.testing.assert_allclose(ns.g[:, rows], _g_by_definition(J, model, free)[:, rows],
                               rtol=2e-14)
    tr = np.trace(J, axis1=1, axis2=2)
    assert np.all(np.abs(ns.model_error) <= 3e-16 * tr)


def test_a_texture_without_the_null_space_is_invalid():
    """A tensor with one more (near-)zero eigenvalue than the model's null space (no
    texture along a direction) is not valid, and gives NaN, in both solvers."""
    from gridflow.estimator._solver import null_space_packed

    model, J, _, free = _planted(n_pixels=40)
    J = J.copy()
    J[:, free[0], :] = 0.0
    J[:, :, free[0]] = 0.0                   # a fourth null direction: e_free0
    ns = null_space(J, model)
    assert not ns.valid.any() and np.isnan(ns.P).all()
    fast = null_space_packed(*_packed(J, model), model)
    assert not fast.valid.any() and np.isnan(fast.P).all()


def test_the_null_space_part_by_part_is_the_same_bits():
    """``null_space_parts`` solves the chunks of the pixels as its parts reach them, a
    few chunks a call; every field of every part is the same bits as the same pixels of
    ``null_space_packed``'s, over parts that end inside chunks, span several, take one
    pixel, and over a run of pixels without the null space (NaN, and the lanes skipped
    after them), so that the chunks' warm starts and their outputs' places are checked.
    """
    from gridflow.estimator._solver import null_space_packed, null_space_parts

    model, J, _, free = _planted(n_pixels=300)
    J = J.copy()
    J[40:120, free[0], :] = 0.0
    J[40:120, :, free[0]] = 0.0
    planes, index = _packed(J, model)
    whole = null_space_packed(planes, index, model)
    assert whole.valid[:40].all() and not whole.valid[40:120].any()
    stops = [5, 70, 71, 200, 233, 300]
    for ahead in (1, 2, 64):
        a = 0
        parts = list(null_space_parts(planes, index, model, stops, ahead=ahead))
        assert len(parts) == len(stops)
        for b, part in zip(stops, parts):
            for got, want in zip(part[:4], whole[:4]):
                assert got.shape == want[a:b].shape
                assert np.array_equal(got, want[a:b], equal_nan=True)
            a = b
    assert sum(p.fallbacks[0] for p in parts) == whole.fallbacks[0] > 0
