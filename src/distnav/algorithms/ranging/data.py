"""The ranging data the UWB solvers work on (paper 002 §2), and their typed result.

:class:`RangingData` is the one definition of what a UWB solver needs from a ranging problem: the arrays (anchor
positions, free coordinates, range samples) and the model of paper 002 computed from them (residuals eq. (6),
cost eqs. (2), (5), Jacobian eq. (9), the measurement graph). :class:`distnav.models.uwb.problems.RangingProblem`
extends it with validation, a name and the generators; the solvers in :mod:`distnav.algorithms.ranging.lm` and
:mod:`distnav.algorithms.ranging.csg` take any :class:`RangingData` (``algorithms`` never imports ``models``).

:class:`RangingResult` is what LM and the CSG family return.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from functools import cached_property
from typing import Any

import numpy as np
import scipy.sparse as sp

from distnav.algorithms.result import ObservationTests, Precision, SolverResult
from distnav.errors import ModelError
from distnav.network.graph import Graph

__all__ = ["RangingData", "RangingResult"]


@dataclass(frozen=True, eq=False)
class RangingData:
    """Anchors, their known / free coordinates and the measured ranges (paper 002 §2).

    Attributes
    ----------
    ids : anchor names (``n``).
    dim : 2 or 3.
    positions_m : ``(n, dim)`` known coordinates: fixed anchors' positions and held coordinates; other entries
        are ignored (0).
    free : ``(n, dim)`` bool, True for the coordinates to estimate (all False for a fixed anchor).
    meas_a, meas_b : anchor indices of every range sample (``m``).
    range_m : the measured ranges ``d_l`` (``m``).
    truth_m, initial_m : optional ``(n, dim)`` true positions and initial guess.
    """

    ids: tuple[str, ...]
    dim: int
    positions_m: np.ndarray
    free: np.ndarray
    meas_a: np.ndarray
    meas_b: np.ndarray
    range_m: np.ndarray
    truth_m: np.ndarray | None = None
    initial_m: np.ndarray | None = None

    # ------------------------------------------------------------------ basic facts
    @property
    def n_anchors(self) -> int:
        return len(self.ids)

    @property
    def n_meas(self) -> int:
        return int(self.range_m.size)

    @cached_property
    def fixed(self) -> np.ndarray:
        """Anchors without any free coordinate (the gauge)."""
        return np.asarray(~self.free.any(axis=1))

    @cached_property
    def estimated(self) -> np.ndarray:
        """Anchors with at least one free coordinate."""
        return np.asarray(self.free.any(axis=1))

    @property
    def n_free(self) -> int:
        return int(self.free.sum())

    @cached_property
    def links(self) -> np.ndarray:
        """Unique measured pairs ``(i, j)``, ``i < j``, sorted."""
        lo = np.minimum(self.meas_a, self.meas_b)
        hi = np.maximum(self.meas_a, self.meas_b)
        key = np.unique(lo * self.n_anchors + hi)
        return np.stack([key // self.n_anchors, key % self.n_anchors], axis=1)

    @cached_property
    def graph(self) -> Graph:
        """The measurement graph G(V, E) (paper 002 §2), also the communication graph of the distributed solvers."""
        pos = self.truth_m if self.truth_m is not None else None
        return Graph.from_links(self.n_anchors, self.links, names=self.ids, positions=pos)

    @cached_property
    def range_sq(self) -> np.ndarray:
        return np.asarray(self.range_m**2)

    def kept_arrays(self, keep: np.ndarray) -> dict[str, Any]:
        """The anchor and range arrays of the anchors where the boolean mask ``keep`` is True: their rows, and the
        range samples between two kept anchors with their ends renumbered in the kept order (the fields of a
        sub-problem; ``dim`` and any subclass fields are the caller's)."""
        idx = np.flatnonzero(keep)
        new = np.full(self.n_anchors, -1, np.int64)
        new[idx] = np.arange(idx.size)
        m = keep[self.meas_a] & keep[self.meas_b]
        return {
            "ids": tuple(self.ids[i] for i in idx),
            "positions_m": self.positions_m[idx],
            "free": self.free[idx],
            "meas_a": new[self.meas_a[m]],
            "meas_b": new[self.meas_b[m]],
            "range_m": self.range_m[m],
            "truth_m": None if self.truth_m is None else self.truth_m[idx],
            "initial_m": None if self.initial_m is None else self.initial_m[idx],
        }

    # ------------------------------------------------------------------ x <-> positions
    @cached_property
    def _col(self) -> np.ndarray:
        """Column of each coordinate in ``x`` (−1 when not free)."""
        col = np.full(self.free.shape, -1, np.int64)
        col[self.free] = np.arange(self.n_free)
        return col

    def to_vector(self, positions_m: np.ndarray) -> np.ndarray:
        """The free coordinates of a full ``(n, dim)`` position array (eq. (1))."""
        p = np.asarray(positions_m, float)
        if p.shape != self.free.shape:
            raise ModelError(f"positions must have shape {self.free.shape}, got {p.shape}")
        return np.asarray(p[self.free])

    def to_positions(self, x: np.ndarray) -> np.ndarray:
        """Full ``(n, dim)`` positions: ``x`` in the free coordinates, known values elsewhere."""
        xv = np.asarray(x, float)
        if xv.shape != (self.n_free,):
            raise ModelError(f"x must have shape ({self.n_free},), got {xv.shape}")
        out = self.positions_m.copy()
        out[self.free] = xv
        return out

    # ------------------------------------------------------------------ eqs. (2)-(6), (9)
    def residuals(self, positions_m: np.ndarray) -> np.ndarray:
        """``g_l = ‖r_a − r_b‖² − d_l²`` for every sample (paper 002 eq. (6)); positions are ``(n, dim)``."""
        p = np.asarray(positions_m, float)
        diff = p[self.meas_a] - p[self.meas_b]
        return np.asarray(np.einsum("ij,ij->i", diff, diff) - self.range_sq)

    def cost(self, positions_m: np.ndarray) -> float:
        """``f = Σ_l g_l²`` (paper 002 eqs. (2), (5))."""
        g = self.residuals(positions_m)
        return float(g @ g)

    def partial_costs(self, positions_m: np.ndarray) -> np.ndarray:
        """``f^[i] = Σ_{l∈E(i)} g_l²`` per anchor at a common point (paper 002 eq. (14)); ``Σ_i f^[i] = 2 f``."""
        g2 = self.residuals(positions_m) ** 2
        n = self.n_anchors
        return np.asarray(np.bincount(self.meas_a, g2, minlength=n) + np.bincount(self.meas_b, g2, minlength=n))

    def residual_vector(self, x: np.ndarray) -> np.ndarray:
        """``g(x)`` of the free-coordinate vector (eq. (5))."""
        return self.residuals(self.to_positions(x))

    @cached_property
    def _jac_structure(self) -> tuple[sp.csr_matrix, np.ndarray, np.ndarray]:
        m, d = self.n_meas, self.dim
        rows = np.concatenate([np.repeat(np.arange(m), d)] * 2)
        cols = np.concatenate([self._col[self.meas_a].ravel(), self._col[self.meas_b].ravel()])
        keep = cols >= 0
        order_id = np.arange(rows.size)[keep]
        mat = sp.csr_matrix((order_id.astype(float) + 1.0, (rows[keep], cols[keep])), shape=(m, self.n_free))
        mat.sort_indices()
        perm = mat.data.astype(np.int64) - 1  # position in the concatenated value array of each CSR entry
        return mat, perm, keep

    def jacobian(self, positions_m: np.ndarray) -> sp.csr_matrix:
        """Sparse ``G = ∂g/∂x`` (``m × n_free``, eq. (9)): row l holds ``2(r_a − r_b)`` at a's free columns
        and ``−2(r_a − r_b)`` at b's."""
        p = np.asarray(positions_m, float)
        diff2 = 2.0 * (p[self.meas_a] - p[self.meas_b])
        vals = np.concatenate([diff2.ravel(), -diff2.ravel()])
        mat, perm, _ = self._jac_structure
        out = mat.copy()
        out.data = vals[perm]
        return out

    def jacobian_of(self, x: np.ndarray) -> sp.csr_matrix:
        return self.jacobian(self.to_positions(x))

    # ------------------------------------------------------------------ the objective in metres
    def distances(self, positions_m: np.ndarray) -> np.ndarray:
        """``‖r_a − r_b‖`` of every sample."""
        p = np.asarray(positions_m, float)
        return np.asarray(np.linalg.norm(p[self.meas_a] - p[self.meas_b], axis=1))

    def residuals_m(self, positions_m: np.ndarray) -> np.ndarray:
        """Range residuals in metres, ``e_l = ‖r_a − r_b‖ − d_l`` (the objective ``Σ e²/σ²`` departs from paper
        002's squared form ``g = ‖r_a − r_b‖² − d²``, whose losses weight every link by about ``d²``)."""
        return np.asarray(self.distances(positions_m) - self.range_m)

    def jacobian_m(self, positions_m: np.ndarray) -> sp.csr_matrix:
        """Sparse ``∂e/∂x`` (``m × n_free``): the unit vector ``u = (r_a − r_b)/‖r_a − r_b‖`` at a's free columns
        and ``−u`` at b's (``u`` = 0 where the two estimates coincide: the residual has no direction there)."""
        p = np.asarray(positions_m, float)
        diff = p[self.meas_a] - p[self.meas_b]
        norm = np.linalg.norm(diff, axis=1)
        u = diff / np.where(norm > 0, norm, np.inf)[:, None]
        vals = np.concatenate([u.ravel(), -u.ravel()])
        mat, perm, _ = self._jac_structure
        out = mat.copy()
        out.data = vals[perm]
        return out


@dataclass(frozen=True, eq=False, kw_only=True)
class RangingResult(SolverResult):
    """Outcome of LM (:func:`~distnav.algorithms.ranging.lm.solve_lm`) or a CSG-family solver (:mod:`~.csg`).

    ``estimates`` are the ``(n, dim)`` anchor positions (for the distributed solvers: every anchor's estimate of
    itself). ``status`` is ``"converged"`` (LM's stopping rule met), ``"max_iterations"`` (the iteration budget
    ran out; the distributed solvers have no stopping rule and always end so unless they blow up) or
    ``"diverged"`` (the estimates or the cost became non-finite — e.g. CSG / N-CSG with a fixed ``α`` too large
    for the geometry: the run stops there, and ``estimates`` are the last, unusable, iterate; ``usable`` is False).

    Attributes
    ----------
    solver : ``"LM"``, ``"CSG"``, ``"N-CSG"``, ``"N-CSG-BLS"``, ``"N-CSG-TBLS"`` or ``"N-CLM"``.
    cost : ``f = Σ g²`` (eq. (2)) at the estimates.
    objective : the robust objective ``Σ s² ρ((g/s)²)`` at the estimates (equal to ``cost`` for the linear loss).
    loss : ``"linear"``, ``"huber"`` or ``"cauchy"``.
    x : LM's estimated free-coordinate vector (eq. (1)); ``None`` for the distributed solvers.
    settings : the solver's step / damping / consensus settings (``alpha``, ``alpha0``, ``lambda0``, …).
    objective_kind : ``"squared"`` (paper 002's ``g = ‖r_a − r_b‖² − d²``) or ``"metres"`` (``e = ‖r_a − r_b‖ − d``,
        weight ``1/σ²``); ``cost`` and ``objective`` are in its units (m⁴, or whitened: dimensionless).
    precision : per-anchor covariance (:class:`~distnav.algorithms.result.Precision`: ``"centralized"`` from LM,
        ``"conditional"`` from what each anchor holds in a distributed solver), or ``None`` where not computed /
        not determined.
    tests : per-sample w-tests (:class:`~distnav.algorithms.result.ObservationTests`), or ``None``.
    offsets_m, offsets_std_m : estimated range offsets (one common, or one per anchor) and their a-posteriori σ.
    """

    solver: str
    cost: float
    objective: float
    loss: str = "linear"
    x: np.ndarray | None = None
    settings: Mapping[str, Any] = field(default_factory=dict)
    objective_kind: str = "squared"
    precision: Precision | None = None
    tests: ObservationTests | None = None
    offsets_m: np.ndarray | None = None
    offsets_std_m: np.ndarray | None = None

    def summary(self) -> dict[str, Any]:
        out = super().summary()
        out.update({"solver": self.solver, "cost": self.cost, "objective": self.objective, "loss": self.loss})
        return out
