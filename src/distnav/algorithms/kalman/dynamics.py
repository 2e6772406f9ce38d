"""The common dynamic model of the Kalman/CKF family — paper 003 eqs. (2), (19)–(20).

``x_t = Φ_t x_{t−1} + d_t``, ``D(d_t) = S_t = H_t S̃_t H_tᵀ`` with ``H_t`` of full column rank and ``S̃_t``
positive definite; a singular ``S_t`` (constant biases) is the normal case. :class:`DynamicModel` validates and
factors the model once; :func:`simulate_states` draws one realization.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from distnav._checks import affordable_nodes, whole_number
from distnav.errors import ModelError
from distnav.typing import ArrayLike, FloatArray, IntArray

__all__ = ["DynamicModel", "noise_factor", "simulate_states"]


def noise_factor(
    noise_cov: ArrayLike, *, rtol: float = 1e-12, epoch: int | None = None
) -> tuple[FloatArray, FloatArray]:
    """Factor a (possibly singular) system-noise variance ``S = H S̃ Hᵀ`` (paper 003 eq. (19)).

    When ``S`` is diagonal-block shaped with zero rows, ``H`` is made of the columns of the identity for the
    entries with noise and ``S̃`` is the corresponding sub-matrix (eq. (20)); otherwise an eigen-decomposition
    ``H = U₊``, ``S̃ = diag(λ₊)`` is used. Returns ``(H (p×q), S̃ (q×q))``; ``q = 0`` when ``S = 0``.
    """
    where = f" at epoch {epoch}" if epoch is not None else ""
    S = np.asarray(noise_cov, dtype=float)
    if S.ndim != 2 or S.shape[0] != S.shape[1]:
        raise ModelError(f"system-noise variance{where} must be square, got shape {S.shape}")
    if not np.all(np.isfinite(S)):
        raise ModelError(f"system-noise variance{where} is not finite")
    scale = float(np.abs(S).max()) if S.size else 0.0
    if not np.allclose(S, S.T, atol=1e-12 * max(scale, 1e-300), rtol=0.0):
        raise ModelError(f"system-noise variance{where} is not symmetric")
    p = S.shape[0]
    if scale == 0.0:
        return np.zeros((p, 0)), np.zeros((0, 0))
    nz = np.flatnonzero(np.abs(S).max(axis=1) > 0)
    sub = S[np.ix_(nz, nz)]
    w = np.linalg.eigvalsh(sub)
    if w.min() < -1e-10 * w.max():
        raise ModelError(f"system-noise variance{where} is not positive semi-definite (eigenvalue {w.min():.3g})")
    if w.min() > rtol * w.max():  # the representation of eq. (20): identity columns + invertible sub-matrix
        return np.eye(p)[:, nz], 0.5 * (sub + sub.T)
    w, U = np.linalg.eigh(S)
    keep = w > rtol * w.max()
    return U[:, keep], np.diag(w[keep])


def _per_epoch(value: ArrayLike, what: str) -> tuple[bool, list[FloatArray]]:
    """(constant?, list of matrices) from a single matrix, a 3-D array or a sequence of matrices."""
    if isinstance(value, np.ndarray) and value.ndim == 2:
        return True, [np.asarray(value, dtype=float)]
    if isinstance(value, np.ndarray) and value.ndim == 3:
        return False, [np.asarray(v, dtype=float) for v in value]
    if isinstance(value, (list, tuple)):
        mats = [np.asarray(v, dtype=float) for v in value]
        if not mats:
            raise ModelError(f"{what}: empty sequence")
        return False, mats
    arr = np.asarray(value, dtype=float)
    if arr.ndim == 2:
        return True, [arr]
    raise ModelError(
        f"{what} must be a matrix, a 3-D array (one per epoch) or a sequence of matrices, got shape {arr.shape}"
    )


def _identity_columns(H: FloatArray) -> IntArray | None:
    """Column indices if every column of ``H`` is a distinct unit vector, else ``None``."""
    if H.shape[1] == 0 or not np.all((H == 0) | (H == 1)) or not np.all(H.sum(axis=0) == 1):
        return None
    sel = np.argmax(H, axis=0)
    return sel if np.unique(sel).size == sel.size else None


class DynamicModel:
    """The common dynamic model ``x_t = Φ_t x_{t−1} + d_t``, ``D(d_t) = S_t = H_t S̃_t H_tᵀ`` (paper 003 eqs. (2), (19)).

    Parameters (each a single matrix = constant in time, or one per epoch as a 3-D array or a sequence;
    entry ``t`` is the model of the step ``t−1 → t``, entry 0 is never used):

    n_states : ``p``.
    transition : ``Φ_t`` (p×p, nonsingular); ``None`` = identity.
    noise_cov : ``S_t`` (p×p, symmetric PSD, may be singular); it is factored with :func:`noise_factor`.
    noise_map, noise_reduced_cov : the factor ``H_t`` (p×q, full column rank) and ``S̃_t`` (q×q, PD) directly,
        instead of ``noise_cov``. Neither given = no system noise (a static state).
    """

    def __init__(
        self,
        n_states: int,
        *,
        transition: ArrayLike | None = None,
        noise_cov: ArrayLike | None = None,
        noise_map: ArrayLike | None = None,
        noise_reduced_cov: ArrayLike | None = None,
    ) -> None:
        p = whole_number(n_states, "n_states", minimum=1, error=ModelError)
        affordable_nodes(p * p, f"n_states={p:,}: a p×p matrix", error=ModelError, items="entries", hint="")
        self.n_states = p
        self._set_transitions(transition)
        self._set_noise(self._noise_pairs(noise_cov, noise_map, noise_reduced_cov))

    def _set_transitions(self, transition: ArrayLike | None) -> None:
        """Check every ``Φ_t`` (finite, nonsingular: paper 003 eq. (2)) and keep it with its inverse."""
        p = self.n_states
        if transition is None:
            self._phi_const, phis = True, [np.eye(p)]
        else:
            self._phi_const, phis = _per_epoch(transition, "transition")
        self._phi: list[np.ndarray] = []
        self._phi_inv: list[np.ndarray | None] = []
        for t, F in enumerate(phis):
            e = "" if self._phi_const else f" of epoch {t}"
            if F.shape != (p, p):
                raise ModelError(f"transition matrix{e} must be {p}×{p}, got {F.shape}")
            if not np.all(np.isfinite(F)):
                raise ModelError(f"transition matrix{e} is not finite")
            if np.array_equal(F, np.eye(p)):
                self._phi.append(F)
                self._phi_inv.append(None)
                continue
            if np.linalg.cond(F) > 1e12:
                raise ModelError(f"transition matrix{e} is singular (paper 003 eq. (2) needs Φ nonsingular)")
            self._phi.append(F)
            self._phi_inv.append(np.linalg.inv(F))

    def _noise_pairs(
        self, noise_cov: ArrayLike | None, noise_map: ArrayLike | None, noise_reduced_cov: ArrayLike | None
    ) -> list[tuple[FloatArray, FloatArray]]:
        """The system noise as ``(H_t, S̃_t)`` per epoch (eq. (19)), from whichever form was given; sets
        ``_noise_const``."""
        p = self.n_states
        if noise_cov is not None and (noise_map is not None or noise_reduced_cov is not None):
            raise ModelError("give either noise_cov or (noise_map, noise_reduced_cov), not both")
        if (noise_map is None) != (noise_reduced_cov is None):
            raise ModelError("noise_map and noise_reduced_cov must be given together")
        if noise_cov is not None:
            self._noise_const, covs = _per_epoch(noise_cov, "noise_cov")
            pairs = []
            for t, S in enumerate(covs):
                if S.shape != (p, p):
                    e = "" if self._noise_const else f" of epoch {t}"
                    raise ModelError(f"noise_cov{e} must be {p}×{p}, got {S.shape}")
                pairs.append(noise_factor(S, epoch=None if self._noise_const else t))
            return pairs
        if noise_map is not None:
            cH, Hs = _per_epoch(noise_map, "noise_map")
            assert noise_reduced_cov is not None  # checked above: both or neither
            cS, Ss = _per_epoch(noise_reduced_cov, "noise_reduced_cov")
            if cH != cS or len(Hs) != len(Ss):
                raise ModelError(
                    "noise_map and noise_reduced_cov must both be constant or both per epoch with the same length"
                )
            self._noise_const = cH
            return list(zip(Hs, Ss, strict=True))
        self._noise_const = True
        return [(np.zeros((p, 0)), np.zeros((0, 0)))]

    def _set_noise(self, pairs: list[tuple[FloatArray, FloatArray]]) -> None:
        """Check every ``(H_t, S̃_t)`` (H full column rank, S̃ symmetric positive definite) and keep them with the
        selection of H's unit columns and S̃'s inverse; an epoch repeating the previous inputs reuses their checks."""
        self._H: list[np.ndarray] = []
        self._sel: list[IntArray | None] = []
        self._sel_slice: list[slice | None] = []
        self._sel_grid: list[tuple[np.ndarray, ...] | None] = []  # np.ix_(sel, sel), for noise_cov_at
        self._St: list[np.ndarray] = []
        self._St_inv: list[np.ndarray] = []
        prev_H: np.ndarray | None = None  # the previous epoch's inputs: a per-epoch model usually repeats
        prev_St: np.ndarray | None = None  # them (one H object, equal S̃ for equal intervals)
        for t, (H, St) in enumerate(pairs):
            e = "" if self._noise_const else f" of epoch {t}"
            if H is prev_H:
                q = H.shape[1]
                self._sel.append(self._sel[-1])
                self._sel_slice.append(self._sel_slice[-1])
                self._sel_grid.append(self._sel_grid[-1])
            else:
                q = self._check_noise_map(H, e)
            self._H.append(H)
            if prev_St is not None and St.shape == (q, q) == prev_St.shape and np.array_equal(St, prev_St):
                self._St.append(self._St[-1])
                self._St_inv.append(self._St_inv[-1])
            else:
                _check_reduced_cov(St, q, e)
                self._St.append(0.5 * (St + St.T))
                self._St_inv.append(np.linalg.inv(St) if q else St.copy())
            prev_H, prev_St = H, St

    def _check_noise_map(self, H: np.ndarray, e: str) -> int:
        """Check ``H`` (rows, finite, full column rank) and keep its unit-column selection; return its columns."""
        p = self.n_states
        if H.ndim != 2 or H.shape[0] != p:
            raise ModelError(f"noise_map{e} must have {p} rows, got shape {H.shape}")
        q = int(H.shape[1])
        if not np.all(np.isfinite(H)):
            raise ModelError(f"system-noise factor{e} is not finite")
        sel = _identity_columns(H)  # distinct unit columns: full column rank without an SVD
        if q and sel is None and np.linalg.matrix_rank(H) < q:
            raise ModelError(f"noise_map{e} must have full column rank (paper 003 eq. (19))")
        self._sel.append(sel)
        self._sel_grid.append(None if sel is None else np.ix_(sel, sel))
        contiguous = sel is not None and bool((np.diff(sel) == 1).all())
        self._sel_slice.append(slice(int(sel[0]), int(sel[-1]) + 1) if contiguous and sel is not None else None)
        return q

    # -- accessors: epoch t ≥ 1 (the step t−1 → t)
    def _idx(self, const: bool, n: int, t: int, what: str) -> int:
        if const:
            return 0
        if t >= n:
            raise ModelError(f"{what} given for {n} epochs, epoch {t} requested")
        return t

    def transition_at(self, t: int) -> FloatArray:
        return self._phi[self._idx(self._phi_const, len(self._phi), t, "transition")]

    def transition_inverse_at(self, t: int) -> FloatArray | None:
        """``Φ_t⁻¹``, or ``None`` when ``Φ_t`` is the identity."""
        return self._phi_inv[self._idx(self._phi_const, len(self._phi), t, "transition")]

    def noise_factor_at(self, t: int) -> tuple[FloatArray, FloatArray, FloatArray]:
        """``(H_t, S̃_t, S̃_t⁻¹)``."""
        k = self._idx(self._noise_const, len(self._H), t, "system noise")
        return self._H[k], self._St[k], self._St_inv[k]

    def noise_selection_at(self, t: int) -> IntArray | None:
        """Indices ``sel`` when ``H_t`` is made of identity columns ``I[:, sel]`` (eq. (20)), else ``None``."""
        k = self._idx(self._noise_const, len(self._H), t, "system noise")
        return self._sel[k]

    def noise_slice_at(self, t: int) -> slice | None:
        """:meth:`noise_selection_at` as a slice when its columns are consecutive and ascending (views instead of
        copies), else ``None``."""
        return self._sel_slice[self._idx(self._noise_const, len(self._H), t, "system noise")]

    def update_at(
        self, t: int
    ) -> tuple[FloatArray | None, FloatArray, FloatArray, FloatArray, slice | IntArray | None]:
        """What the time update to epoch ``t`` needs in one look-up: ``(Φ_t⁻¹ or None, H_t, S̃_t, S̃_t⁻¹, sel)``,
        ``sel`` the slice of :meth:`noise_slice_at`, else the indices of :meth:`noise_selection_at`, else None."""
        phi_inv = self._phi_inv[self._idx(self._phi_const, len(self._phi), t, "transition")]
        k = self._idx(self._noise_const, len(self._H), t, "system noise")
        cut = self._sel_slice[k]
        return phi_inv, self._H[k], self._St[k], self._St_inv[k], self._sel[k] if cut is None else cut

    def noise_cov_at(self, t: int) -> FloatArray:
        """``S_t = H_t S̃_t H_tᵀ``."""
        k = self._idx(self._noise_const, len(self._H), t, "system noise")
        grid = self._sel_grid[k]
        if grid is not None:  # H = identity columns: S̃ placed in the rows/columns `sel` (exactly H S̃ Hᵀ)
            S: FloatArray = np.zeros((self.n_states, self.n_states))
            S[grid] = self._St[k]
            return S
        H, St = self._H[k], self._St[k]
        S = H @ St @ H.T
        return S

    def noise_cov_block(self, epochs: IntArray) -> FloatArray:
        """:meth:`noise_cov_at` of several epochs, ``(B, p, p)`` (the same numbers; one array filled at once where
        ``H`` is made of identity columns)."""
        ts = np.asarray(epochs, np.int64).tolist()
        ks = [self._idx(self._noise_const, len(self._H), t, "system noise") for t in ts]
        sels = {None if self._sel[k] is None else self._sel[k].tobytes() for k in ks}  # type: ignore[union-attr]
        if len(sels) != 1 or self._sel[ks[0]] is None:
            return np.stack([self.noise_cov_at(t) for t in ts]).reshape(len(ts), self.n_states, self.n_states)
        sel = np.asarray(self._sel[ks[0]])
        S: FloatArray = np.zeros((len(ts), self.n_states, self.n_states))
        S[:, sel[:, None], sel[None, :]] = np.stack([self._St[k] for k in ks]) if ks else 0.0
        return S

    def check_epochs(self, n_epochs: int) -> None:
        if not self._phi_const and len(self._phi) < n_epochs:
            raise ModelError(f"transition given for {len(self._phi)} epochs, the measurements have {n_epochs}")
        if not self._noise_const and len(self._H) < n_epochs:
            raise ModelError(f"system noise given for {len(self._H)} epochs, the measurements have {n_epochs}")

    @classmethod
    def random_walk(cls, noise_std: FloatArray | Sequence[float]) -> DynamicModel:
        """``Φ = I``, ``S = diag(noise_std²)`` (zeros allowed: constant entries)."""
        s = np.asarray(noise_std, dtype=float)
        if s.ndim != 1 or np.any(s < 0) or not np.all(np.isfinite(s)):
            raise ModelError("noise_std must be a 1-D array of non-negative finite values")
        return cls(s.size, noise_cov=np.diag(s**2))

    def __repr__(self) -> str:
        q = self._H[0].shape[1]
        return f"DynamicModel(n_states={self.n_states}, noise rank={q}{'' if self._noise_const else ' (varying)'})"


def simulate_states(
    dynamics: DynamicModel, n_epochs: int, *, rng: np.random.Generator, initial_state: ArrayLike | None = None
) -> FloatArray:
    """One realization ``x_0..x_{T−1}`` (T×p) of the dynamic model; ``x_0 = initial_state`` (default zeros)."""
    p = dynamics.n_states
    x = np.zeros((n_epochs, p))
    x[0] = 0.0 if initial_state is None else np.asarray(initial_state, float)
    for t in range(1, n_epochs):
        H, St, _ = dynamics.noise_factor_at(t)
        d = H @ (np.linalg.cholesky(St) @ rng.standard_normal(St.shape[0])) if St.size else 0.0
        x[t] = dynamics.transition_at(t) @ x[t - 1] + d
    return x


def _check_reduced_cov(St: np.ndarray, q: int, e: str) -> None:
    """``S̃`` must be q×q, finite, symmetric and positive definite (paper 003 eq. (19) needs it invertible)."""
    if St.shape != (q, q):
        raise ModelError(f"noise_reduced_cov{e} must be {q}×{q} to match noise_map, got {St.shape}")
    if not np.all(np.isfinite(St)):
        raise ModelError(f"system-noise factor{e} is not finite")
    if q:
        if not np.allclose(St, St.T, rtol=0, atol=1e-12 * np.abs(St).max()):
            raise ModelError(f"noise_reduced_cov{e} is not symmetric")
        try:
            np.linalg.cholesky(St)
        except np.linalg.LinAlgError:
            raise ModelError(
                f"noise_reduced_cov{e} is not positive definite (paper 003 eq. (19) needs S̃ invertible)"
            ) from None
