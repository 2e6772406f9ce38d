"""The per-anchor check's Gauss–Newton (distnav.models.uwb.local) against a plain reference iteration."""

from __future__ import annotations

import numpy as np
import pytest

from distnav.models.uwb.local import _gauss_newton


def reference_gn(y0: np.ndarray, qf: np.ndarray, dh: np.ndarray) -> np.ndarray:
    y = np.array(y0, float)
    for _ in range(20):
        diff = y - qf
        r = np.sqrt(np.einsum("ij,ij->i", diff, diff))
        j = diff / np.maximum(r, 1e-9)[:, None]
        try:
            step = np.linalg.solve(j.T @ j, j.T @ (dh - r))
        except np.linalg.LinAlgError:
            step, *_ = np.linalg.lstsq(j, dh - r, rcond=None)
        y = y + step
        if float(step @ step) < 1e-14:
            break
    return y


@pytest.mark.parametrize("k", [2, 3])
def test_batched_gauss_newton_matches_one_start_at_a_time(k):
    rng = np.random.default_rng(k)
    for _ in range(30):
        qf = rng.uniform(0.0, 20.0, (int(rng.integers(k + 1, 8)), k))
        at = rng.uniform(0.0, 20.0, k)
        dh = np.linalg.norm(at - qf, axis=1) + rng.normal(0.0, 0.2, qf.shape[0])
        starts = np.stack([at + rng.normal(0.0, 3.0, k), rng.uniform(0.0, 20.0, k), qf[0].copy()])  # one on a node
        got = _gauss_newton(starts, qf, dh)
        for s, g in zip(starts, got, strict=True):
            np.testing.assert_allclose(g, reference_gn(s, qf, dh), rtol=0, atol=1e-9)
