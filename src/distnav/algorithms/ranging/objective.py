"""The centralized ranging objectives LM minimises: paper 002's squared form, the range residual in metres, and
range-bias calibration (a common offset or per-anchor antenna delays with a prior).

* ``"squared"`` (paper 002 eq. (6)): ``g_l = ‖r_a − r_b‖² − d_l²``, unweighted; a robust loss acts on ``g`` with the
  scale ``s_l = 2 d_l σ_loss`` (:func:`~distnav.algorithms.ranging.losses.range_loss_scale`).
* ``"metres"``: ``e_l = ‖r_a − r_b‖ + b_l − d_l`` whitened by the range σ, ``r_l = e_l / σ_l`` (weight ``1/σ²``), a
  robust loss on ``r`` with the scale ``σ_loss / σ_l`` — i.e. it switches at range errors of about ``σ_loss``
  metres whatever the link's length. ``b_l`` is the range bias: 0, a common offset ``b`` (every range reads ``b``
  too long), the sum ``b_a + b_b`` of the two anchors' antenna delays (``"per_anchor"``), or both,
  ``c + b_a + b_b`` (``"common_delays"``, issue 28: a common offset with no prior and per-anchor delays about it).
  Per-anchor delays are not separable from the geometry without a prior: each gets a pseudo-observation
  ``b_i / σ_b = 0`` (``offset_prior_sigma_m``); prior rows are never down-weighted by the loss. With
  ``"common_delays"`` the prior also fixes the one direction the ranges cannot see (every ``b_i`` up by ``k``,
  ``c`` down by ``2k``): it is a hierarchical prior ``δ_i = c/2 + b_i ~ N(c/2, σ_b²)`` on the anchors' total
  delays with an unknown mean (prior information as pseudo-observations: Theil & Goldberger 1961, mixed
  estimation), where ``"per_anchor"`` holds that mean at 0 and so pulls a common offset of decimetres into the
  geometry (docs/uwb.md, "Antenna delays about a common offset").

The free vector is ``x = [free coordinates (eq. (1)), offsets]``; the offsets are ``[b]``, ``[b_1 … b_n]`` or
``[c, b_1 … b_n]``.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numpy as np
import scipy.sparse as sp

from distnav._checks import real_array
from distnav.algorithms.ranging.data import RangingData
from distnav.errors import ModelError

__all__ = ["DELAY_MODES", "OFFSETS", "FitOptions", "RangeObjective", "check_fit", "range_sigma"]

OFFSETS = ("none", "common", "per_anchor", "common_delays")
#: the modes whose per-anchor delays carry the prior ``N(0, offset_prior_sigma_m²)``
DELAY_MODES = ("per_anchor", "common_delays")
_PRIOR_SCALE = 1e30  # the loss scale of prior rows: ρ(z) = z for every loss


def _sigma_values(sigma_m: float | np.ndarray) -> np.ndarray:
    """``sigma_m`` as a real array, refused by name unless every value is finite and positive."""
    s = real_array(sigma_m, "sigma_m", error=ModelError)
    if not np.all(np.isfinite(s)) or np.any(s <= 0):
        raise ModelError(f"sigma_m must be finite and positive (one value or one per range sample), got {sigma_m!r}")
    return s


def range_sigma(problem: RangingData, sigma_m: float | np.ndarray) -> np.ndarray:
    """The range σ of every sample (a scalar is broadcast); must be finite and positive."""
    return np.broadcast_to(_sigma_values(sigma_m), problem.range_m.shape).copy()


def check_sigma(objective: str, sigma_m: float | np.ndarray) -> None:
    """Refuse a ``sigma_m`` that is not finite and positive, and one given with the squared objective, which
    weights every range alike (paper 002 eq. (2)) and would ignore it silently."""
    s = _sigma_values(sigma_m)
    if objective == "squared" and not (s.ndim == 0 and float(s) == 1.0):
        raise ModelError(
            f"sigma_m={sigma_m!r} is used by objective='metres' only: the squared objective (paper 002 eq. (2)) "
            f"weights every range alike; pass objective='metres' to weight the ranges by their σ"
        )


def check_fit(objective: str, range_offsets: str, offset_prior_sigma_m: float) -> None:
    """Refuse by name an unknown objective or offset mode, offsets with the squared objective and a non-positive
    prior σ of per-anchor offsets (every ranging front door's fit: LM's and the distributed solvers')."""
    if objective not in ("squared", "metres"):
        raise ModelError(f"objective must be 'squared' or 'metres', got {objective!r}")
    if range_offsets not in OFFSETS:
        raise ModelError(f"range offsets must be one of {', '.join(OFFSETS)}, got {range_offsets!r}")
    if range_offsets != "none" and objective != "metres":
        raise ModelError("range offsets are estimated with objective='metres' only")
    if range_offsets in DELAY_MODES and not offset_prior_sigma_m > 0:
        raise ModelError(f"offset_prior_sigma_m must be positive, got {offset_prior_sigma_m}")


@dataclass(frozen=True, kw_only=True)
class FitOptions:
    """What every ranging front door fits and tests, LM (:class:`~distnav.algorithms.ranging.lm.LMSolveOptions`)
    and the distributed solvers (:class:`~distnav.algorithms.ranging.options.RunOptions`).

    - ``initial_m`` (None: the problem's start): the ``(n, dim)`` start positions, metres.
    - ``objective`` (``"squared"``, paper 002 eq. (2); or ``"metres"``): the residuals fitted.
    - ``sigma_m`` (1.0): the ranges' standard deviation for the metres objective (a value or one per range), metres.
    - ``range_offsets`` (``"none"``; ``"common"`` / ``"per_anchor"`` / ``"common_delays"`` with the metres
      objective; the last LM's only): range offsets estimated with the positions; ``offset_prior_sigma_m`` (0.1):
      the per-anchor delays' prior σ, metres (``b_i`` in ``b_a + b_b``: ``PLANT_HARD``'s delays are 0.05 m so; LM
      can estimate it, ``LMSolveOptions.estimate_offset_prior``).
    - ``quality`` (True): the per-anchor covariance and the w-tests of the links; ``test_level`` (0.001): their
      significance level; ``test_scale`` (``"robust"``): their variance factor.
    """

    initial_m: np.ndarray | None = None
    objective: str = "squared"
    sigma_m: float | np.ndarray = 1.0
    range_offsets: str = "none"
    offset_prior_sigma_m: float = 0.1
    quality: bool = True
    test_level: float = 0.001
    test_scale: str = "robust"

    def __post_init__(self) -> None:
        check_fit(self.objective, self.range_offsets, self.offset_prior_sigma_m)
        check_sigma(self.objective, self.sigma_m)


@dataclass(frozen=True, eq=False)
class RangeObjective:
    """Whitened residuals and their Jacobian for LM on a ranging problem (see the module docstring)."""

    problem: RangingData
    kind: str = "squared"
    sigma_m: float | np.ndarray = 1.0
    offsets: str = "none"
    offset_prior_sigma_m: float = 0.1

    def __post_init__(self) -> None:
        check_fit(self.kind, self.offsets, self.offset_prior_sigma_m)
        check_sigma(self.kind, self.sigma_m)

    @cached_property
    def sigma(self) -> np.ndarray:
        return range_sigma(self.problem, self.sigma_m)

    @property
    def n_offsets(self) -> int:
        n = self.problem.n_anchors
        return {"none": 0, "common": 1, "per_anchor": n, "common_delays": n + 1}[self.offsets]

    @property
    def n_prior(self) -> int:
        return self.problem.n_anchors if self.offsets in DELAY_MODES else 0

    @property
    def n_x(self) -> int:
        return self.problem.n_free + self.n_offsets

    def x0(self, initial_m: np.ndarray) -> np.ndarray:
        return np.concatenate([self.problem.to_vector(initial_m), np.zeros(self.n_offsets)])

    def split(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``(positions (n, dim), offsets)`` of a free vector."""
        nf = self.problem.n_free
        return self.problem.to_positions(x[:nf]), np.asarray(x[nf:])

    def sample_offsets(self, offsets: np.ndarray) -> np.ndarray:
        """``b_l`` of every sample."""
        p = self.problem
        if self.offsets == "common":
            return np.full(p.n_meas, float(offsets[0]))
        if self.offsets == "per_anchor":
            return np.asarray(offsets[p.meas_a] + offsets[p.meas_b])
        if self.offsets == "common_delays":
            return np.asarray(offsets[0] + offsets[1 + p.meas_a] + offsets[1 + p.meas_b])
        return np.zeros(p.n_meas)

    def anchor_offsets(self, offsets: np.ndarray) -> np.ndarray:
        """Every anchor's total delay ``δ_i`` with ``b_l = δ_a + δ_b`` (``"per_anchor"``: ``b_i``;
        ``"common_delays"``: ``c/2 + b_i``); the offsets themselves for ``"none"`` / ``"common"``."""
        off = np.asarray(offsets, float)
        return np.asarray(0.5 * off[0] + off[1:]) if self.offsets == "common_delays" else off

    def anchor_offsets_map(self) -> np.ndarray:
        """The matrix ``T`` with :meth:`anchor_offsets` ``= T @ offsets`` (for their covariance ``T Q Tᵀ``)."""
        n = self.n_offsets
        if self.offsets != "common_delays":
            return np.eye(n)
        return np.hstack([np.full((n - 1, 1), 0.5), np.eye(n - 1)])

    def residual(self, x: np.ndarray) -> np.ndarray:
        pos, off = self.split(x)
        if self.kind == "squared":
            return self.problem.residuals(pos)
        r = (self.problem.distances(pos) + self.sample_offsets(off) - self.problem.range_m) / self.sigma
        if self.n_prior:
            r = np.concatenate([r, off[off.size - self.n_prior :] / self.offset_prior_sigma_m])  # the delays b_i
        return np.asarray(r)

    def jacobian(self, x: np.ndarray) -> sp.csr_matrix:
        pos, _ = self.split(x)
        p = self.problem
        if self.kind == "squared":
            return p.jacobian(pos)
        jac = sp.diags(1.0 / self.sigma) @ p.jacobian_m(pos)
        if self.offsets == "none":
            return sp.csr_matrix(jac)
        common = sp.csr_matrix((1.0 / self.sigma)[:, None])
        if self.offsets == "common":
            cols = common
        else:
            m, n = p.n_meas, p.n_anchors
            rows = np.concatenate([np.arange(m)] * 2)
            cols = sp.csr_matrix(
                (np.concatenate([1.0 / self.sigma] * 2), (rows, np.concatenate([p.meas_a, p.meas_b]))), shape=(m, n)
            )
            if self.offsets == "common_delays":
                cols = sp.hstack([common, cols])
        top = sp.hstack([jac, cols])
        if not self.n_prior:
            return sp.csr_matrix(top)
        lead = p.n_free + self.n_offsets - self.n_prior  # the columns before the delays: coordinates (and c)
        prior = sp.hstack(
            [
                sp.csr_matrix((self.n_prior, lead)),
                sp.identity(self.n_prior, format="csr") / self.offset_prior_sigma_m,
            ]
        )
        return sp.csr_matrix(sp.vstack([top, prior]))

    def loss_scale(self, loss_scale_m: float) -> np.ndarray:
        """Scale of every residual for the robust loss (prior rows: never down-weighted)."""
        if not loss_scale_m > 0:
            raise ModelError(f"loss_scale_m must be positive, got {loss_scale_m}")
        p = self.problem
        if self.kind == "squared":
            return np.asarray(2.0 * np.maximum(p.range_m, loss_scale_m) * loss_scale_m)
        return np.concatenate([loss_scale_m / self.sigma, np.full(self.n_prior, _PRIOR_SCALE)])
