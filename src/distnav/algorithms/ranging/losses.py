"""The robust losses of the ranging family (scipy's conventions; paper 002 with IRLS, see
:mod:`distnav.algorithms.ranging.lm`): the bottom of the family, imported by LM, the neighbourhood solvers, QC,
precision and covariance alike."""

from __future__ import annotations

from typing import Any

import numpy as np

from distnav.algorithms.ranging.data import RangingData
from distnav.errors import ModelError

__all__ = ["LOSSES", "OBJECTIVES", "loss_terms", "robust_weights", "range_loss_scale"]

LOSSES = ("linear", "huber", "soft_l1", "cauchy", "cauchy_long")
OBJECTIVES = ("squared", "metres")


def __getattr__(name: str) -> Any:
    if name == "RangingLike":  # the protocol that restated RangingProblem; one definition now: RangingData
        import warnings

        warnings.warn(
            "distnav.algorithms.ranging.lm.RangingLike is deprecated: use distnav.algorithms.ranging.data.RangingData",
            DeprecationWarning,
            stacklevel=2,
        )
        return RangingData
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def loss_terms(g: np.ndarray, scale: np.ndarray | float, loss: str) -> tuple[np.ndarray, np.ndarray]:
    """Per-residual IRLS weights ``ρ'((g/s)²)`` and objective terms ``s² ρ((g/s)²)`` (linear: 1 and ``g²``).

    scipy's conventions (``least_squares(loss=...)``): Huber ``ρ(z) = z`` for ``z ≤ 1`` else ``2√z − 1``;
    soft-L1 ``ρ(z) = 2(√(1 + z) − 1)``; Cauchy ``ρ(z) = ln(1 + z)``.

    ``"cauchy_long"`` is one-sided: Cauchy where the range reads *long* (``g < 0``, with ``g`` = fitted − measured)
    and linear (Gaussian) where it reads short. NLOS and multipath only lengthen a UWB range, so a link measured
    much shorter than the fit is evidence against the fit, not an outlier to ignore. Weight and ``ρ`` are C¹ at 0.
    """
    if loss == "linear":
        return np.ones_like(g), g * g
    s = np.broadcast_to(np.asarray(scale, float), g.shape)
    z = (g / s) ** 2
    if loss == "huber":
        small = z <= 1.0
        rz = np.where(small, z, 2.0 * np.sqrt(z) - 1.0)
        w = np.where(small, 1.0, 1.0 / np.sqrt(np.maximum(z, 1.0)))
    elif loss == "soft_l1":
        t = np.sqrt(1.0 + z)
        rz = 2.0 * (t - 1.0)
        w = 1.0 / t
    elif loss == "cauchy":
        rz = np.log1p(z)
        w = 1.0 / (1.0 + z)
    elif loss == "cauchy_long":
        long = g < 0
        rz = np.where(long, np.log1p(z), z)
        w = np.where(long, 1.0 / (1.0 + z), 1.0)
    else:
        raise ModelError(f"unknown loss {loss!r}; choose one of {', '.join(LOSSES)}")
    return np.asarray(w), np.asarray(s * s * rz)


def robust_weights(g: np.ndarray, scale: np.ndarray | float, loss: str) -> tuple[np.ndarray, float]:
    """Per-residual IRLS weights ``ρ'((g/s)²)`` and the objective ``Σ s² ρ((g/s)²)`` (linear: 1 and ``Σ g²``)."""
    if loss == "linear":
        return np.ones_like(g), float(g @ g)
    w, terms = loss_terms(g, scale, loss)
    return w, float(np.sum(terms))


def range_loss_scale(problem: RangingData, loss_scale_m: float) -> np.ndarray:
    """Residual scale ``s_l = 2 d_l σ`` of ``g_l = ‖r_a − r_b‖² − d_l²`` for a range error of ``σ`` metres
    (``g ≈ 2 d (‖r_a − r_b‖ − d)``), so the robust loss switches at range errors of about ``loss_scale_m``."""
    if not loss_scale_m > 0:
        raise ModelError(f"loss_scale_m must be positive, got {loss_scale_m}")
    return np.asarray(2.0 * np.maximum(problem.range_m, loss_scale_m) * loss_scale_m)
