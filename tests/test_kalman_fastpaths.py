"""The filter stage's shortcuts (issue 14, time target) against the general forms they replace.

Each shortcut must give exactly what the general computation gives: the system noise placed by its selected
rows/columns vs ``H S̃ Hᵀ``, the single-filter pseudo-inverse vs the grouped batch path, the node-subset design
rows vs building them for those nodes alone, the cheap node-id check still rejecting bad ids, and the kernel's
decompositions on one BLAS thread vs the same code under the caller's thread count.
"""

from __future__ import annotations

import numpy as np
import pytest

from distnav._blas import _openblas_handles
from distnav.algorithms.kalman import DynamicModel, pseudo_inverse_psd
from distnav.errors import ModelError
from distnav.models.gnss.gfbias import BiasGeometryFreeSeries, BiasStateLayout


def test_noise_cov_by_selection_equals_product() -> None:
    p, sel = 7, [1, 4, 5]
    H = np.eye(p)[:, sel]
    rng = np.random.default_rng(0)
    m = rng.standard_normal((3, 3))
    St = m @ m.T + np.eye(3)
    dyn = DynamicModel(p, noise_map=H, noise_reduced_cov=St)
    assert dyn.noise_selection_at(1) is not None
    np.testing.assert_array_equal(dyn.noise_cov_at(1), H @ dyn.noise_factor_at(1)[1] @ H.T)
    # a general (non-selection) map keeps the product
    G = rng.standard_normal((p, 2))
    dyn2 = DynamicModel(p, noise_map=G, noise_reduced_cov=np.eye(2))
    assert dyn2.noise_selection_at(1) is None
    np.testing.assert_array_equal(dyn2.noise_cov_at(1), G @ np.eye(2) @ G.T)


@pytest.mark.parametrize("singular", [False, True])
def test_single_filter_pseudo_inverse_equals_batched_path(singular: bool) -> None:
    rng = np.random.default_rng(1)
    p = 6
    a = rng.standard_normal((4 if singular else 9, p))
    info = a.T @ a
    info[2, :] = info[:, 2] = 0.0  # never observed: dropped before the inverse
    inv1, est1 = pseudo_inverse_psd(info[None])
    # the same matrix twice, with a second row that has another unseen pattern: the grouped path
    other = info.copy()
    other[4, :] = other[:, 4] = 0.0
    inv2, est2 = pseudo_inverse_psd(np.stack([info, other]))
    np.testing.assert_array_equal(inv1[0], inv2[0])
    np.testing.assert_array_equal(est1[0], est2[0])
    assert not est1[0, 2]
    assert (est1[0].sum() < p - 1) if singular else (est1[0].sum() == p - 1)  # rank 4 of 5 seen: a null space
    if not singular:
        seen = np.r_[0:2, 3:p]
        np.testing.assert_allclose(
            inv1[0][np.ix_(seen, seen)], np.linalg.inv(info[np.ix_(seen, seen)]), rtol=1e-10, atol=1e-12
        )


def _series(seed: int) -> BiasGeometryFreeSeries:
    rng = np.random.default_rng(seed)
    T, n, S = 5, 3, 6
    lay = BiasStateLayout(tuple(f"G{k:02d}" for k in range(S)), ("A", "B", "C"), n_ionospheres=2, reference="B")
    coef = rng.standard_normal((T, n, S, 3))
    sig = rng.uniform(0.2, 1.0, (T, n, S))
    tracked = rng.random((T, n, S)) > 0.3
    obs = rng.standard_normal((T, n, S))
    return BiasGeometryFreeSeries(lay, coef, sig, obs_m=obs, tracked=tracked, groups=np.array([0, 1, 1]))


def test_subset_design_equals_design_built_for_those_nodes() -> None:
    ser = _series(2)
    for t in range(ser.n_epochs):
        A_all, w_all = ser.design(t)
        for nodes in ([0], [2], [1, 2], [2, 0]):
            fresh = _series(2)  # nothing cached: built for these nodes directly
            A, w = fresh.design(t, np.array(nodes))
            np.testing.assert_array_equal(A, A_all[nodes])
            np.testing.assert_array_equal(w, w_all[nodes])
            N, r = fresh.normals(t, np.array(nodes))
            Aw = A_all[nodes] * w_all[nodes][..., None]
            np.testing.assert_allclose(N, np.swapaxes(Aw, 1, 2) @ A_all[nodes], rtol=1e-14, atol=1e-14)
        # node C (ionosphere 1): its TEC coefficients in columns 3–5, none in ionosphere 0's; its own bias column
        A, w = ser.design(t, np.array([2]))
        on = w[0] > 0
        assert np.all(A[0, :, 0:3] == 0.0)
        np.testing.assert_array_equal(A[0, on, 3:6], ser._a[t, 2][on])
        np.testing.assert_array_equal(A[0, :, ser.layout.receiver_column()[2]], on.astype(float))


def test_node_id_fast_path_still_rejects_bad_ids() -> None:
    ser = _series(3)
    with pytest.raises(ModelError, match="0..2"):
        ser.node_ids(np.array([0, 3], np.int64))
    with pytest.raises(ModelError, match="0..2"):
        ser.node_ids(np.array([-1], np.int64))
    np.testing.assert_array_equal(ser.node_ids(np.array([2, 0], np.int64)), [2, 0])


def _blas_threads() -> list[int]:
    return [int(get()) for _set, get in _openblas_handles()]


def test_pseudo_inverse_fallback_on_one_blas_thread_equals_svd_reference() -> None:
    """Regular, singular (the eigen-decomposition fallback, run on one BLAS thread) and partly unseen rows, as in a
    session's first epochs, against an SVD pseudo-inverse of the scaled matrix (another LAPACK path); the caller's
    BLAS thread count is restored."""
    rng = np.random.default_rng(5)
    p = 31
    rows = []
    for rank in (p + 5, p - 1, p - 3):
        a = rng.standard_normal((rank, p)) * rng.uniform(0.1, 10.0, p)
        rows.append(a.T @ a)
    info = np.stack(rows)
    info[2, 7, :] = info[2, :, 7] = 0.0
    before = _blas_threads()
    inv, est = pseudo_inverse_psd(info)
    assert _blas_threads() == before
    for k, rank in enumerate((p, p - 1, p - 3)):
        seen = np.flatnonzero(np.diagonal(info[k]) > 0)
        sub = info[k][np.ix_(seen, seen)]
        d = 1.0 / np.sqrt(np.diagonal(sub))
        C = sub * d[:, None] * d[None, :]
        ref = np.linalg.pinv(C, rcond=1e-10, hermitian=False) * d[:, None] * d[None, :]
        u, sv, _ = np.linalg.svd(C)
        null = u[:, sv <= 1e-10 * sv[0]]
        est_ref = (null**2).sum(axis=1) < 1e-8
        assert np.linalg.matrix_rank(C) == min(rank, seen.size)
        np.testing.assert_array_equal(est[k, seen], est_ref)
        assert est[k].sum() < p if k else est[k].all()  # both paths taken
        np.testing.assert_allclose(inv[k][np.ix_(seen, seen)], ref, rtol=1e-8, atol=1e-9 * np.abs(ref).max())


def test_per_epoch_model_reusing_repeated_inputs_equals_direct_computation() -> None:
    """A per-epoch noise model given one ``H`` object and equal ``S̃`` (equal intervals) reuses the previous
    epoch's checks, selection and inverse; every accessor equals the quantity computed directly for that epoch
    (``S̃⁻¹`` by its own inverse, ``S = H S̃ Hᵀ``), for a selection ``H`` and a general one."""
    rng = np.random.default_rng(7)
    p, T = 8, 9
    for H, sel in ((np.eye(p)[:, [0, 2, 3]], [0, 2, 3]), (rng.standard_normal((p, 3)), None)):
        m = rng.standard_normal((3, 3))
        base = m @ m.T + np.eye(3)
        St = [base * (2.0 if t in (4, 5) else 1.0) for t in range(T)]  # runs of equal values, distinct objects
        dyn = DynamicModel(p, noise_map=[H] * T, noise_reduced_cov=St)
        for t in range(1, T):
            Ht, St_t, St_inv = dyn.noise_factor_at(t)
            assert Ht is H
            np.testing.assert_array_equal(St_t, 0.5 * (St[t] + St[t].T))
            np.testing.assert_array_equal(St_inv, np.linalg.inv(St[t]))
            np.testing.assert_allclose(dyn.noise_cov_at(t), H @ St[t] @ H.T, rtol=1e-14, atol=1e-14)
            got = dyn.noise_selection_at(t)
            if sel is None:
                assert got is None
            else:
                assert got is not None and np.array_equal(got, sel)


def test_per_epoch_model_still_checks_changed_inputs() -> None:
    p, T = 6, 4
    H = np.eye(p)[:, [1, 2]]
    good = np.eye(2)
    with pytest.raises(ModelError, match="epoch 2 is not positive definite"):
        DynamicModel(p, noise_map=[H] * T, noise_reduced_cov=[good, good, -good, good])
    H3 = np.eye(p)[:, [1, 2, 4]]
    with pytest.raises(ModelError, match=r"epoch 1 must be 3×3"):  # a new H of other rank, the same S̃
        DynamicModel(p, noise_map=[H, H3, H3, H3], noise_reduced_cov=[good] * T)
    flat = np.ones((p, 2))  # not identity columns, rank 1
    with pytest.raises(ModelError, match="epoch 1 must have full column rank"):
        DynamicModel(p, noise_map=[H, flat, flat, flat], noise_reduced_cov=[good] * T)


def test_noise_cov_block_is_h_s_ht_at_every_epoch() -> None:
    """The collectors' block of system-noise covariances equals ``H_t S̃_t H_tᵀ`` formed by hand, epoch by epoch,
    for identity-column maps varying in size over the epochs and for a general map."""
    from distnav.algorithms.kalman import DynamicModel

    rng = np.random.default_rng(3)
    H = np.eye(5)[:, [1, 3]]
    covs = [np.diag(rng.uniform(0.1, 2.0, 2)) for _ in range(6)]
    dyn = DynamicModel(5, noise_map=[H] * 6, noise_reduced_cov=covs)
    got = dyn.noise_cov_block(np.arange(1, 6))
    np.testing.assert_array_equal(got, np.stack([H @ c @ H.T for c in covs[1:]]))
    G = rng.standard_normal((5, 2))
    general = DynamicModel(5, noise_map=G, noise_reduced_cov=covs[0])
    np.testing.assert_allclose(general.noise_cov_block(np.array([1, 2])), np.stack([G @ covs[0] @ G.T] * 2))
