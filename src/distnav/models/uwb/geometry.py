"""Geometry and ambiguity checks of a ranging problem, made before solving (issue 13, item 4).

A solver given an undetermined or ambiguous network still returns numbers, and they look as good as any. These
pure functions say beforehand which anchors the ranges can locate, and how well:

* **Cut-off parts** (``disconnected``): anchors whose part of the range graph holds no known anchor cannot be
  placed in the known anchors' frame. They are reported *unsolved*; the rest is solved.
* **Non-rigid parts** (``non_rigid``): an anchor that can move while every range stays the same (a single link,
  two links in 3-D, a part hinged on two anchors, a part with one known anchor that can rotate). Test: the
  rank of the rigidity matrix (rows ``(p_a − p_b)ᵀ`` at a's and ``−(p_a − p_b)ᵀ`` at b's free coordinates,
  i.e. the Jacobian of the ranges) at **random** positions (generic rigidity, Asimow & Roth 1978): an anchor
  with a component in its null space is flexible. Unsolved too; the test is repeated on the rest.
* **Flips** (``flip``): an anchor measured to exactly as many others as it has free coordinates (2 links in
  2-D or with its height held, 3 in 3-D) is rigid but has a second, mirrored position fitting its ranges as
  well (reflected through the line or plane of its neighbours). *Ambiguous*: the issue's "2 links left one
  anchor 8–9 m off, converged".
* **Mirror of the whole network** (``mirror``): the known anchors of a part lie on one line (2-D, or 3-D with the
  heights held: their horizontal positions), or in 3-D with free heights on one plane (always the case with 3
  known anchors): the reflection through that line / plane keeps every range and every known position, so the
  ranges cannot choose between the solution and its mirror image. *Ambiguous*. Known anchors *nearly* on one
  line (``near_line``: second over first principal spread below ``planar_tol``; ``near_mirror`` for
  known anchors nearly on one plane with free heights) make the solve *weakly determined*, and ``uwb solve``
  then runs the mirror test (:mod:`distnav.models.uwb.mirror`): on the APRIL lab data with known nodes 8, 61,
  12 (node 12 0.3 m off the line of the other two, ratio 0.049) the mirror image fits the real ranges *better*
  (Cauchy cost 84 against 108 near the truth) and LM returned it, 4.1 m RMSE, as ``converged``.
* **Nearly planar network solved in 3-D** (``planar``): anchors under a ceiling lie within decimetres of one
  plane; with free heights the ranges constrain the heights only to second order and each anchor can fold
  through the plane. Measured by :func:`planarity` (smallest / largest principal spread) of the known anchors
  and of the initial guess of the whole network; below ``planar_tol`` (0.1 by default: a 2 m height span across
  20 m is planar) the solve is *refused* unless ``allow_planar_3d=True`` (then *weakly determined*). The remedy
  is to hold the surveyed heights (``--heights``). The network's planarity is that of the initial guess (an
  MDS of the ranges) where there is one, else that of the known anchors. The MDS start of a planar network is
  not planar itself (heights enter the ranges to second order only, so its third dimension carries noise and NLOS:
  0.07–0.18 on simulated halls whose truth is 0.01), so a network is also called planar when its ranges fit a
  plane about as well as 3-D space (:func:`planar_fit_ratio`: median |range residual| of a 2-D SMACOF embedding
  over that of the 3-D one below ``PLANAR_FIT_RATIO`` = 3; simulated halls 1.0–2.1, volumetric networks 18–52).
  Known anchors that are nearly but not exactly coplanar in a network that is not planar (``near_mirror``) make
  the solve *weakly determined*.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass, field
from typing import Any, Literal

import numpy as np
import scipy.linalg as sla
import scipy.sparse as sp
from scipy.sparse.csgraph import connected_components, reverse_cuthill_mckee

from distnav._blas import single_threaded_blas
from distnav.errors import ModelError
from distnav.models.uwb.initial import classical_mds, completed, link_distances, smacof
from distnav.models.uwb.problems import RangingProblem
from distnav.typing import BoolArray, FloatArray, IntArray

__all__ = [
    "GeometryIssue",
    "GeometryReport",
    "check_geometry",
    "rigidity_matrix",
    "flexible_anchors",
    "planarity",
    "planar_fit_ratio",
    "PLANAR_TOL",
    "PLANAR_FIT_RATIO",
    "MAX_DENSE_RIGIDITY",
]

PLANAR_TOL = 0.1
PLANAR_FIT_RATIO = 3.0
EXACT_TOL = 1e-6
MAX_DENSE_RIGIDITY = 6000
NULL_TOL = 1e-9  # eigenvalues of RᵀR at most this × the largest span its null space
Severity = Literal["unsolved", "ambiguous", "weakly_determined", "refused"]


@dataclass(frozen=True)
class GeometryIssue:
    """One finding: ``kind`` (disconnected, non_rigid, flip, mirror, planar), what it means for the solve
    (``severity``), the anchors concerned and a message for a user."""

    kind: str
    severity: Severity
    anchors: tuple[str, ...]
    message: str

    def as_dict(self) -> dict[str, Any]:
        return {"kind": self.kind, "severity": self.severity, "anchors": list(self.anchors), "message": self.message}


@dataclass(frozen=True, eq=False)
class GeometryReport:
    """What :func:`check_geometry` found. ``solvable`` marks the anchors the ranges can locate (known anchors
    included); ``planarity_known`` / ``planarity_network`` are ``None`` where not computed (2-D, heights held,
    no initial guess)."""

    ids: tuple[str, ...]
    solvable: BoolArray
    issues: tuple[GeometryIssue, ...] = ()
    planarity_known: float | None = None
    planarity_network: float | None = None
    notes: tuple[str, ...] = field(default=())
    planar_fit_ratio: float | None = None

    @property
    def unsolved(self) -> tuple[str, ...]:
        return tuple(k for k, s in zip(self.ids, self.solvable, strict=True) if not s)

    @property
    def refused(self) -> tuple[GeometryIssue, ...]:
        return tuple(i for i in self.issues if i.severity == "refused")

    @property
    def status(self) -> Literal["ambiguous", "weakly_determined"] | None:
        """The worst :data:`~distnav.algorithms.result.SolverStatus` the geometry allows (None: no concern)."""
        sev = {i.severity for i in self.issues}
        if "ambiguous" in sev:
            return "ambiguous"
        if "weakly_determined" in sev:
            return "weakly_determined"
        return None

    def ambiguous_anchors(self) -> set[str]:
        out: set[str] = set()
        for i in self.issues:
            if i.severity == "ambiguous":
                out.update(i.anchors)
        return out

    def messages(self) -> list[str]:
        return [i.message for i in self.issues]

    def raise_if_refused(self) -> None:
        if self.refused:
            raise ModelError("; ".join(i.message for i in self.refused))

    def as_dict(self) -> dict[str, Any]:
        return {
            "status": self.status,
            "unsolved": list(self.unsolved),
            "issues": [i.as_dict() for i in self.issues],
            "planarity_known": self.planarity_known,
            "planarity_network": self.planarity_network,
            "planar_fit_ratio": self.planar_fit_ratio,
            "notes": list(self.notes),
        }


def planarity(points_m: FloatArray) -> float:
    """Smallest over largest principal spread of 3-D points (0 = coplanar; 0 for fewer than 4 points)."""
    p = np.asarray(points_m, float)
    if p.shape[0] < 4 or p.shape[1] < 3:
        return 0.0
    s = np.linalg.svd(p - p.mean(axis=0), compute_uv=False)
    return float(s[-1] / s[0]) if s[0] > 0 else 0.0


def planar_fit_ratio(problem: RangingProblem, keep: BoolArray | None = None) -> float:
    """How much better the ranges fit 3-D space than a plane: median |‖x_a − x_b‖ − d_ab| over the measured pairs
    of a 2-D SMACOF embedding over that of a 3-D one (classical MDS start, :mod:`distnav.models.uwb.initial`; the
    3-D median floored at 2 cm, about the scatter of a UWB range, so that exact simulated ranges do not make a
    ceiling network volumetric). ≈ 1 when the ranges cannot see the heights (anchors under a ceiling), ≫ 1 for a
    volumetric network. ``keep`` restricts it to the anchors kept."""
    sub = problem if keep is None or keep.all() else problem.subset(keep, check=False)
    links, d = link_distances(sub, False)
    full = completed(sub, links, d)
    med = []
    with single_threaded_blas():
        for k in (2, 3):
            x = smacof(links, d, classical_mds(full, k))
            med.append(float(np.median(np.abs(np.linalg.norm(x[links[:, 0]] - x[links[:, 1]], axis=1) - d))))
    return med[0] / max(med[1], 0.02)


def _line_ratio(points: FloatArray) -> float:
    """Second over first principal spread (0 = collinear; 0 for fewer than 3 points)."""
    if points.shape[0] < 3:
        return 0.0
    s = np.linalg.svd(points - points.mean(axis=0), compute_uv=False)
    return float(s[1] / s[0]) if s[0] > 0 else 0.0


def _off_line_m(points: FloatArray) -> float:
    """Largest distance of 2-D points from their principal (best-fit) line."""
    c = points - points.mean(axis=0)
    _, _, vt = np.linalg.svd(c, full_matrices=False)
    return float(np.abs(c @ vt[-1]).max())


def rigidity_matrix(problem: RangingProblem, positions_m: FloatArray) -> sp.csr_matrix:
    """Rigidity matrix of the measured links (one row per link) at ``positions_m``, columns = free coordinates."""
    links = problem.links
    p = np.asarray(positions_m, float)
    diff = p[links[:, 0]] - p[links[:, 1]]
    col = np.full(problem.free.shape, -1, np.int64)
    col[problem.free] = np.arange(problem.n_free)
    rows = np.repeat(np.arange(links.shape[0]), problem.dim)
    ca, cb = col[links[:, 0]].ravel(), col[links[:, 1]].ravel()
    r = np.concatenate([rows, rows])
    c = np.concatenate([ca, cb])
    v = np.concatenate([diff.ravel(), -diff.ravel()])
    keep = c >= 0
    return sp.csr_matrix((v[keep], (r[keep], c[keep])), shape=(links.shape[0], problem.n_free))


def _clearly_rigid(normal: sp.csr_matrix, rel_tol: float = NULL_TOL) -> bool:
    """True if ``RᵀR`` has no eigenvalue ≤ ``rel_tol · λ_max`` (so :func:`flexible_anchors`' eigendecomposition
    would find no null space), decided by one Cholesky factorization instead of ``eigh``: with ``τ = rel_tol ×``
    the Gershgorin bound (≥ ``λ_max``), ``RᵀR − τI`` is positive definite — its Cholesky succeeds — exactly when
    every eigenvalue exceeds ``τ ≥ rel_tol · λ_max`` (Sylvester's inertia). The factorization is banded after a
    reverse Cuthill–McKee ordering (anchor networks are geometric graphs). False means "maybe not": the caller
    runs the full eigendecomposition."""
    n = normal.shape[0]
    gersh = float(np.max(np.asarray(abs(normal).sum(axis=1)).ravel(), initial=0.0))
    if n == 0 or gersh <= 0.0:
        return False
    shifted = sp.csr_matrix(normal - sp.identity(n, format="csr") * (rel_tol * gersh))
    perm = np.asarray(reverse_cuthill_mckee(shifted, symmetric_mode=True), np.int64)
    a = shifted[perm][:, perm].tocoo()
    band = int(np.max(np.abs(a.row - a.col), initial=0))
    try:
        if band <= max(8, n // 4):
            ab = np.zeros((band + 1, n))
            up = a.row <= a.col
            ab[band + a.row[up] - a.col[up], a.col[up]] = a.data[up]
            sla.cholesky_banded(ab, lower=False, check_finite=False)
        else:
            sla.cholesky(a.toarray(), lower=False, check_finite=False)
    except (np.linalg.LinAlgError, ValueError):
        return False
    return True


def flexible_anchors(problem: RangingProblem, rng: np.random.Generator | None = None) -> BoolArray:
    """Anchors that can move without changing any range (generic rigidity at random positions; see module)."""
    n_free = problem.n_free
    out = np.zeros(problem.n_anchors, bool)
    if n_free == 0:
        return out
    g = rng if rng is not None else np.random.default_rng(20240613)
    pos = g.normal(0.0, 1.0, size=(problem.n_anchors, problem.dim))
    r = rigidity_matrix(problem, pos)
    normal_sp = sp.csr_matrix(r.T @ r)
    with single_threaded_blas():
        if _clearly_rigid(normal_sp):
            return out
        w, v = np.linalg.eigh(normal_sp.toarray())
    null = v[:, w <= NULL_TOL * max(float(w[-1]), 1e-300)]
    if null.shape[1] == 0:
        return out
    energy = np.einsum("ij,ij->i", null, null)  # diagonal of the null-space projector, per free coordinate
    owner = np.nonzero(problem.free)[0]
    per_anchor = np.bincount(owner, energy, minlength=problem.n_anchors)
    out[:] = per_anchor > 1e-8
    return out


def _components(problem: RangingProblem, keep: BoolArray) -> Iterator[IntArray]:
    lk = problem.links
    m = keep[lk[:, 0]] & keep[lk[:, 1]]
    n = problem.n_anchors
    adj = sp.csr_matrix((np.ones(int(m.sum())), (lk[m, 0], lk[m, 1])), shape=(n, n))
    _, labels = connected_components(adj, directed=False)
    for lab in np.unique(labels[keep]):
        yield np.flatnonzero((labels == lab) & keep)


def _names(problem: RangingProblem, idx: IntArray | list[int], limit: int = 12) -> str:
    shown = ", ".join(repr(problem.ids[i]) for i in list(idx)[:limit])
    return shown + (f" and {len(idx) - limit} more" if len(idx) > limit else "")


def check_geometry(
    problem: RangingProblem,
    *,
    allow_planar_3d: bool = False,
    planar_tol: float = PLANAR_TOL,
    initial_m: FloatArray | None = None,
    rng: np.random.Generator | None = None,
) -> GeometryReport:
    """Run every check of the module docstring on ``problem`` (built with ``check_determined=False`` if it may
    be undetermined). ``initial_m`` (default ``problem.initial_m``) is used for the network's planarity."""
    keep = np.ones(problem.n_anchors, bool)
    issues: list[GeometryIssue] = []
    notes: list[str] = []
    _unreachable(problem, keep, issues)  # 1. parts of the range graph without a known anchor
    _non_rigid(problem, keep, issues, notes, rng)  # 2. non-rigid parts
    _flips(problem, keep, issues)  # 3. flips: exactly as many neighbours as free coordinates
    # 4. mirror of a whole part, nearly planar 3-D solve
    z_free = problem.dim == 3 and bool(problem.free[keep & problem.estimated, 2].any())
    init = problem.initial_m if initial_m is None else np.asarray(initial_m, float)
    pk, pn = _mirrors(problem, keep, issues, z_free, planar_tol, init)
    fit_ratio = _planar(problem, keep, issues, z_free, (pk, pn), planar_tol, allow_planar_3d)
    return GeometryReport(
        ids=problem.ids,
        solvable=keep,
        issues=tuple(issues),
        planarity_known=pk,
        planarity_network=pn,
        notes=tuple(notes),
        planar_fit_ratio=fit_ratio,
    )


def _unreachable(problem: RangingProblem, keep: BoolArray, issues: list[GeometryIssue]) -> None:
    """Step 1: anchors with no chain of links to a known anchor are taken out of ``keep`` (unsolved)."""
    lost: list[int] = []
    for comp in _components(problem, keep):
        if not problem.fixed[comp].any():
            lost += comp.tolist()
    if lost:
        why = f"anchors {_names(problem, lost)} have no chain of measured links to a known anchor: left unsolved"
        _leave_unsolved(problem, keep, issues, lost, "disconnected", why)


def _leave_unsolved(
    problem: RangingProblem, keep: BoolArray, issues: list[GeometryIssue], anchors: Any, kind: str, why: str
) -> None:
    """Take ``anchors`` (indices) out of ``keep`` and record why: an ``"unsolved"`` issue of ``kind``."""
    keep[anchors] = False
    issues.append(GeometryIssue(kind, "unsolved", tuple(problem.ids[i] for i in anchors), why))


def _non_rigid(
    problem: RangingProblem,
    keep: BoolArray,
    issues: list[GeometryIssue],
    notes: list[str],
    rng: np.random.Generator | None,
) -> None:
    """Step 2: flexible anchors out of ``keep`` (repeated: removing a flexible anchor can leave another one)."""
    for _ in range(4):
        if not (keep & problem.estimated).any():
            break
        if problem.n_free > MAX_DENSE_RIGIDITY:
            notes.append(f"rigidity test skipped: {problem.n_free} unknowns > {MAX_DENSE_RIGIDITY}")
            break
        sub = problem.subset(keep, check=False)
        flex_sub = flexible_anchors(sub, rng)
        if not flex_sub.any():
            break
        flex = np.flatnonzero(keep)[flex_sub]
        why = (
            f"anchors {_names(problem, flex)} can move without changing any range (not "
            f"rigid: too few links, or a part hinged on too few anchors): left unsolved"
        )
        _leave_unsolved(problem, keep, issues, flex, "non_rigid", why)


def _flips(problem: RangingProblem, keep: BoolArray, issues: list[GeometryIssue]) -> None:
    """Step 3: an anchor with exactly as many neighbours as free coordinates is ambiguous (its flip)."""
    lk = problem.links
    m = keep[lk[:, 0]] & keep[lk[:, 1]]
    degree = np.bincount(lk[m].ravel(), minlength=problem.n_anchors)
    k_free = problem.free.sum(axis=1)
    for i in np.flatnonzero(keep & (k_free > 0) & (degree == k_free)):
        nb = np.concatenate([lk[m & (lk[:, 0] == i), 1], lk[m & (lk[:, 1] == i), 0]])
        issues.append(
            GeometryIssue(
                "flip",
                "ambiguous",
                (problem.ids[i],),
                f"anchor {problem.ids[i]!r} has only {degree[i]} links (to {_names(problem, nb.tolist())}) for "
                f"{k_free[i]} free coordinates: its mirror image through them fits the ranges as well (ambiguous); "
                f"it needs at least {k_free[i] + 1}",
            )
        )


def _mirrors(
    problem: RangingProblem,
    keep: BoolArray,
    issues: list[GeometryIssue],
    z_free: bool,
    planar_tol: float,
    init: FloatArray | None,
) -> tuple[float | None, float | None]:
    """Step 4a, per part with estimated anchors: known anchors on (nearly) one line (heights held or 2-D) or on one
    plane (free heights). Returns the smallest planarity of the known anchors and of the initial guess (3-D, free
    heights; None otherwise)."""
    pk: float | None = None
    pn: float | None = None
    for comp in _components(problem, keep):
        if not problem.estimated[comp].any():
            continue
        kf = comp[problem.fixed[comp]]
        estimated = tuple(problem.ids[i] for i in comp if problem.estimated[i])
        if not z_free:
            _line_mirror(problem, kf, estimated, issues, planar_tol)
            continue
        pk_c = planarity(problem.positions_m[kf])
        pk = pk_c if pk is None else min(pk, pk_c)
        if init is not None and comp.size >= 4:
            pn_c = planarity(np.asarray(init)[comp])
            pn = pn_c if pn is None else min(pn, pn_c)
        if pk_c <= EXACT_TOL:
            issues.append(
                GeometryIssue(
                    "mirror",
                    "ambiguous",
                    estimated,
                    f"the {kf.size} known anchors {_names(problem, kf.tolist())} lie in one plane and the heights are "
                    f"free: the mirror image of the network through that plane fits every range equally (ambiguous); "
                    f"hold the surveyed heights (--heights) or add a known anchor off the plane",
                )
            )
    return pk, pn


def _line_mirror(
    problem: RangingProblem, kf: IntArray, estimated: tuple[str, ...], issues: list[GeometryIssue], planar_tol: float
) -> None:
    """A part whose known anchors ``kf`` lie on one line (``mirror``, ambiguous) or nearly (``near_line``: the
    mirror test of :mod:`distnav.models.uwb.mirror`), 2-D or 3-D with the heights held."""
    ratio = _line_ratio(problem.positions_m[kf][:, :2])
    what = "2-D" if problem.dim == 2 else "3-D with the heights held"
    if ratio <= EXACT_TOL:
        issues.append(
            GeometryIssue(
                "mirror",
                "ambiguous",
                estimated,
                f"the {kf.size} known anchor(s) {_names(problem, kf.tolist())} lie on one line ({what}): the "
                f"mirror image of the network through that line fits every range equally (ambiguous); add a "
                f"known anchor off the line",
            )
        )
    elif ratio < planar_tol:
        issues.append(
            GeometryIssue(
                "near_line",
                "weakly_determined",
                estimated,
                f"the {kf.size} known anchors {_names(problem, kf.tolist())} lie nearly on one line ({what}; "
                f"none more than {_off_line_m(problem.positions_m[kf][:, :2]):.2f} m off it, line ratio "
                f"{ratio:.3f} < {planar_tol}): the mirror image of the network through that line fits the "
                f"ranges almost as well, range errors can choose it (weakly determined); add a known anchor "
                f"farther off the line",
            )
        )


def _planar(
    problem: RangingProblem,
    keep: BoolArray,
    issues: list[GeometryIssue],
    z_free: bool,
    planarities: tuple[float | None, float | None],
    planar_tol: float,
    allow_planar_3d: bool,
) -> float | None:
    """Step 4b: a nearly planar network solved in 3-D with free heights (refused unless ``allow_planar_3d``) or
    nearly coplanar known anchors (``near_mirror``). Returns the planar fit ratio where it was computed."""
    pk, pn = planarities
    network_planar = pn if pn is not None else pk
    fit_ratio: float | None = None
    if z_free and pn is not None and pn >= planar_tol:  # a planar network's MDS start need not be planar
        try:
            fit_ratio = planar_fit_ratio(problem, keep)
        except ModelError:  # not connected: no embedding
            fit_ratio = None
    fits_plane = fit_ratio is not None and fit_ratio < PLANAR_FIT_RATIO
    estimated = tuple(problem.ids[i] for i in np.flatnonzero(keep & problem.estimated))
    if z_free and network_planar is not None and (network_planar < planar_tol or fits_plane):
        sev: Severity = "weakly_determined" if allow_planar_3d else "refused"
        tail = (
            "solved as asked: heights are weakly determined"
            if allow_planar_3d
            else "refused: hold the surveyed heights (--heights HEIGHTS.csv) or ask for it with --allow-planar-3d"
        )
        issues.append(
            GeometryIssue(
                "planar",
                sev,
                estimated,
                "the network is nearly planar (planarity of the known anchors "
                f"{pk if pk is not None else float('nan'):.3f}"
                f", of the initial guess {pn if pn is not None else float('nan'):.3f}"
                + (
                    f"; its ranges fit a plane about as well as 3-D space: median residual ratio {fit_ratio:.2f} < "
                    f"{PLANAR_FIT_RATIO:g}"
                    if fits_plane
                    else f", < {planar_tol}"
                )
                + ") and is solved in 3-D with free heights: the ranges cannot tell above from below its plane; "
                + tail,
            )
        )
    elif z_free and pk is not None and EXACT_TOL < pk < planar_tol:
        issues.append(
            GeometryIssue(
                "near_mirror",
                "weakly_determined",
                estimated,
                f"the known anchors are nearly coplanar (planarity {pk:.3f} < {planar_tol}) and the heights are free: "
                f"the mirror image through their plane fits the ranges almost as well (weakly determined)",
            )
        )
    return fit_ratio
