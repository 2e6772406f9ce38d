"""The Chebyshev inner solve of the LM phase (algorithms/ranging/chebyshev.py, issue 27, tried): its spectrum
bounds hold the eigenvalues of the block-Jacobi-preconditioned damped normal matrix (dense eigenvalues, numpy),
its iteration count is Saad's bound, and after that many iterations the A-norm error is below the forcing term
(against numpy's dense solve)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from distnav.algorithms.ranging import chebyshev
from distnav.algorithms.ranging import refine as R
from distnav.algorithms.ranging.csg import solve
from test_ranging_refine import OPTS, corner_hall


@pytest.fixture(scope="module")
def first_round():
    """The corner hall's first LM linearization (the refiner and its ``_Linearization``), captured from a solve."""
    seen = []
    step = R._Refiner.step

    def capture(self, lin, mu, cg_max):
        seen.append((self, lin))
        return step(self, lin, mu, cg_max)

    R._Refiner.step = capture
    try:
        solve(corner_hall(), "N-CLM", iterations=500, **OPTS)
    finally:
        R._Refiner.step = step
    return seen[0]


def _system(run, lin, mu):
    """The damped system at ``mu`` (float64 on the wire), its preconditioner, and their dense matrices over the
    free parameters and the common offset (columns of the operator applied to unit vectors)."""
    free = run.free
    damp, damp_c = mu * np.maximum(lin.diag, 1e-12), mu * max(lin.dc, 1e-12)
    pre_inv = R.block_preconditioner(lin.own_block, damp, free)
    pre_c = lin.dc + damp_c
    args = (lin.a, lin.cn, lin.e, lin.w, damp, damp_c, run.prior, free, run.common, np.float64, None)
    system = R.NormalSystem(run.links, run.owner, *args)
    idx = np.argwhere(free)
    n = len(idx) + 1
    A, Minv = np.zeros((n, n)), np.zeros((n, n))
    for j in range(n):
        v, vc = np.zeros((run.nl, run.P, 1)), np.zeros(1)
        if j < len(idx):
            v[idx[j][0], idx[j][1], 0] = 1.0
        else:
            vc[0] = 1.0
        q, share = system.matvec(v, vc)
        A[:, j] = np.r_[q[idx[:, 0], idx[:, 1], 0], share.sum() + damp_c * vc[0]]
        mv = np.einsum("nab,nbk->nak", pre_inv, v)
        Minv[:, j] = np.r_[mv[idx[:, 0], idx[:, 1], 0], vc[0] / pre_c]
    return system, pre_inv, pre_c, damp, damp_c, A, Minv, idx


def _plain(values, dtype):
    return np.asarray(values, float)


@pytest.mark.parametrize("mu", [1e-4, 1e-2, 1.0, 100.0])
def test_bounds_hold_the_preconditioned_spectrum(first_round, mu):
    run, lin = first_round
    _, pre_inv, pre_c, damp, damp_c, A, Minv, _ = _system(run, lin, mu)
    ev = np.linalg.eigvals(Minv @ A)
    assert np.max(np.abs(ev.imag)) < 1e-9 * np.max(ev.real)  # similar to a symmetric positive definite matrix
    lo, hi = chebyshev.spectrum_bounds(lin, run.owner, run.free, damp, damp_c, pre_inv, pre_c, mu, _plain)
    assert 0 < lo <= ev.real.min()
    assert hi >= ev.real.max()
    assert lo >= 0.99 * mu / (run.P + mu)  # the block's β ≤ P (module docstring)


def test_iterations_for_is_saads_bound():
    # κ = 100: q = 9/11, 2qᵐ ≤ 0.1 first at m = ⌈ln 20 / ln(11/9)⌉ = ⌈14.93⌉
    assert chebyshev.iterations_for(0.01, 1.0, 0.1) == 15
    assert 2 * (9 / 11) ** 15 <= 0.1 < 2 * (9 / 11) ** 14
    assert chebyshev.iterations_for(1.0, 1.0, 0.1) == 1


def test_chebyshev_error_falls_by_the_forcing_term(first_round):
    run, lin = first_round
    mu = 0.1
    system, pre_inv, pre_c, damp, damp_c, A, _, idx = _system(run, lin, mu)
    bounds = chebyshev.spectrum_bounds(lin, run.owner, run.free, damp, damp_c, pre_inv, pre_c, mu, _plain)
    b = -np.where(run.free, lin.g, 0.0)[:, :, None]
    x, xc, its = chebyshev.chebyshev(system, b, np.array([-lin.gc]), pre_inv, pre_c, _plain, bounds, 10**4, 0.1)
    assert its == chebyshev.iterations_for(*bounds, 0.1)
    exact = np.linalg.solve(A, np.r_[b[idx[:, 0], idx[:, 1], 0], -lin.gc])
    err = np.r_[x[idx[:, 0], idx[:, 1], 0], xc] - exact
    assert math.sqrt(err @ A @ err) <= 0.1 * math.sqrt(exact @ A @ exact)  # x₀ = 0: e₀ = the solution
    assert np.all(x[~run.free] == 0.0)
