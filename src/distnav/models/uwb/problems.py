"""UWB anchor self-localization: the ranging model of paper 002 and its test-problem generators.

Model (paper 002 §2; restored forms in ``shared/papers/README.md``)
------------------------------------------------------------------
``n`` anchors with 2-D or 3-D positions ``r_i``; some are *fixed* (their positions define the frame, the gauge),
the others are *estimated*. Every measured range ``d_l`` between anchors ``a_l`` and ``b_l`` contributes one
residual (eq. (6))::

    g_l(x) = ‖r_{a_l} − r_{b_l}‖² − d_l²            (no square root: no singularity when estimates coincide)

and the cost is (eqs. (2), (5)) ``f(x) = Σ_l g_l(x)² = gᵀg``. A link measured several times contributes one
residual per sample. ``x`` stacks the *free* coordinates (eq. (1)): every coordinate of an estimated anchor,
except coordinates that are held at a known value (e.g. anchor heights under a ceiling, ``held``).
The Jacobian ``G = ∂g/∂x`` (eq. (9)) has two non-zero blocks per row, ``±2 (r_a − r_b)ᵀ``; it is returned sparse.

Determinacy is checked when a problem is built (:class:`~distnav.errors.ModelError` names the anchor / link):
every estimated anchor must be connected through measured links to a fixed anchor; in 3-D there must be at
least 3 non-collinear fixed anchors (2 distinct ones in 2-D, or in 3-D when every estimated anchor's height is
held); a link may only name known anchors and never an anchor with itself; ranges must be finite and ≥ 0.

Generators (paper 002 §4)
-------------------------
:func:`generate_problem` builds one instance of the classes G (10 m grid, 8-neighbourhood), L (two-row ladder,
the same 8-neighbourhood rule, degree ≤ 5), R (random placement, links up to 18 m), 100 anchors, 3 fixed,
selections C (a corner), O (opposite corners), M (middle); ranging noise ``N(0, 0.15² m²)``; initial guess
``truth + U(−5, 5) m`` per coordinate (eq. (23)). The anchors lie in a horizontal plane (z = 0) and are solved
in 3-D, as in the paper.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import connected_components

from distnav._checks import affordable_nodes, check_field_types, real_array, real_number, whole_number
from distnav._settings import resolve_options
from distnav.algorithms.ranging.data import RangingData
from distnav.errors import ModelError

__all__ = [
    "RangingProblem",
    "ProblemOptions",
    "PaperProblemOptions",
    "build_problem",
    "generate_problem",
    "generate_layout",
    "select_fixed",
    "PROBLEM_CLASSES",
    "SELECTIONS",
    "PAPER_PROBLEMS",
    "rmse_m",
]

PROBLEM_CLASSES = ("G", "L", "R")
SELECTIONS = {"G": ("C", "O", "M"), "L": ("C", "O", "M"), "R": ("C", "M")}
PAPER_PROBLEMS = ("GC", "GO", "GM", "LC", "LO", "LM", "RC", "RM")


def _collinear(points: np.ndarray, tol: float = 1e-6) -> bool:
    """True when all ``points`` (k × dim) lie on one line (or coincide), relative to their spread."""
    p = np.asarray(points, float)
    if p.shape[0] < 3:
        return True
    c = p - p.mean(axis=0)
    s = np.linalg.svd(c, compute_uv=False)
    if s[0] == 0:
        return True
    return bool(s[1] <= tol * s[0])


@dataclass(frozen=True, eq=False)
class RangingProblem(RangingData):
    """An anchor network with measured ranges; see the module docstring for the model.

    Build with :func:`build_problem` (validates) or :func:`generate_problem`. The arrays and the model
    (residuals, cost, Jacobian, graph) are those of :class:`~distnav.algorithms.ranging.data.RangingData` (``ids``,
    ``dim``, ``positions_m``, ``free``, ``meas_a``, ``meas_b``, ``range_m``, ``truth_m``, ``initial_m``); this
    class adds a label and free-form information.

    Attributes
    ----------
    name : a label such as ``"GC"``.
    info : how the problem was made (class, selection, noise, …).
    """

    name: str = ""
    info: Mapping[str, Any] = field(default_factory=dict)

    def x0(self) -> np.ndarray:
        """The initial guess as a vector of free coordinates."""
        if self.initial_m is None:
            raise ModelError(f"problem {self.name or ''} has no initial guess; pass one")
        return self.to_vector(self.initial_m)

    # ------------------------------------------------------------------ derived problems
    def with_initial(self, initial_m: np.ndarray) -> RangingProblem:
        init = _check_positions(initial_m, self.n_anchors, self.dim, "initial guess", self.ids)
        init = np.where(self.free, init, self.positions_m)
        return _replace(self, initial_m=init)

    def with_ranges(self, range_m: np.ndarray) -> RangingProblem:
        r = np.asarray(range_m, float)
        if r.shape != self.range_m.shape:
            raise ModelError(f"need {self.range_m.size} ranges, got shape {r.shape}")
        _check_ranges(r, self.meas_a, self.meas_b, self.ids)
        return _replace(self, range_m=r)

    def subset(self, keep: np.ndarray, *, check: bool = True) -> RangingProblem:
        """The problem on the anchors where ``keep`` is True (and the ranges among them), re-validated
        (``check``) as by :func:`build_problem`; ``info["subset_of"]`` keeps the original anchor indices."""
        k = np.asarray(keep, bool)
        if k.shape != (self.n_anchors,):
            raise ModelError(f"keep must have shape ({self.n_anchors},), got {k.shape}")
        kept = self.kept_arrays(k)
        if not kept["range_m"].size:
            raise ModelError("the kept anchors have no range between them")
        info = dict(self.info)
        info["subset_of"] = np.flatnonzero(k).tolist()
        out = _replace(self, **kept, info=info)
        if check:
            _check_determined(out.ids, out.dim, out.positions_m, out.free, out.fixed, out.meas_a, out.meas_b)
        return out

    def describe(self) -> str:
        return (
            f"{self.name or 'problem'}: {self.n_anchors} anchors ({int(self.fixed.sum())} fixed), "
            f"{self.dim}-D, {self.links.shape[0]} links, {self.n_meas} ranges, {self.n_free} unknowns"
        )


def _replace(p: RangingProblem, **changes: Any) -> RangingProblem:
    kw = {
        f: getattr(p, f)
        for f in (
            "ids",
            "dim",
            "positions_m",
            "free",
            "meas_a",
            "meas_b",
            "range_m",
            "truth_m",
            "initial_m",
            "name",
            "info",
        )
    }
    kw.update(changes)
    return RangingProblem(**kw)


def rmse_m(problem: RangingProblem, positions_m: np.ndarray, truth_m: np.ndarray | None = None) -> float:
    """Estimation error over estimated anchors, paper 002 eq. (24): ``sqrt((1/n_e) Σ_i ‖r̂_i − r_i‖²)``."""
    truth = truth_m if truth_m is not None else problem.truth_m
    if truth is None:
        raise ModelError("RMSE needs the true positions")
    est = problem.estimated
    d = np.asarray(positions_m, float)[est] - np.asarray(truth, float)[est]
    return float(np.sqrt(np.mean(np.einsum("ij,ij->i", d, d)))) if est.any() else 0.0


# ---------------------------------------------------------------------- validation
def _check_positions(pos: Any, n: int, dim: int, what: str, ids: Sequence[str]) -> np.ndarray:
    p = np.asarray(pos, float)
    if p.shape != (n, dim):
        raise ModelError(f"{what} must have shape ({n}, {dim}), got {p.shape}")
    bad = ~np.isfinite(p).all(axis=1)
    if bad.any():
        raise ModelError(f"{what} of anchor {ids[int(np.argmax(bad))]!r} is not finite")
    return p


def _check_ranges(r: np.ndarray, a: np.ndarray, b: np.ndarray, ids: Sequence[str]) -> None:
    bad = ~np.isfinite(r)
    if bad.any():
        k = int(np.argmax(bad))
        raise ModelError(f"range #{k} between {ids[a[k]]!r} and {ids[b[k]]!r} is not finite ({r[k]})")
    neg = r < 0
    if neg.any():
        k = int(np.argmax(neg))
        raise ModelError(f"range #{k} between {ids[a[k]]!r} and {ids[b[k]]!r} is negative ({r[k]} m)")


@dataclass(frozen=True, kw_only=True)
class ProblemOptions:
    """What :func:`build_problem` knows of a problem besides its samples.

    - ``fixed`` (None: no fixed anchor): every fixed anchor's id → its position, metres.
    - ``dim`` (3; or 2): the dimension.
    - ``held`` (None): an estimated anchor's id → ``{axis: value}`` of coordinates held, metres.
    - ``initial_m`` / ``truth_m`` (None): ``(n, dim)`` start and true positions, metres.
    - ``name`` (``""``) and ``info`` (None: empty): the problem's name and free-form description.
    - ``check_determined`` (True): refuse a problem that is not determined (module docstring).
    """

    fixed: Mapping[str, Any] | None = None
    dim: int = 3
    held: Mapping[str, Mapping[int, float]] | None = None
    initial_m: np.ndarray | None = None
    truth_m: np.ndarray | None = None
    name: str = ""
    info: Mapping[str, Any] | None = None
    check_determined: bool = True


def build_problem(
    ids: Sequence[str],
    links: Sequence[tuple[Any, Any]] | np.ndarray,
    range_m: Sequence[float] | np.ndarray,
    *,
    options: ProblemOptions | None = None,
    **changes: Any,
) -> RangingProblem:
    """Build and validate a :class:`RangingProblem`.

    ``links`` name the two anchors of every range sample, by id (``str``) or index (``int``); ``range_m`` holds
    one range per sample (several samples of one pair are allowed). ``fixed`` maps the id of every fixed anchor
    to its position. ``held`` maps an estimated anchor's id to ``{axis: value}`` of coordinates to hold (e.g.
    ``{"A7": {2: 2.85}}`` holds A7's height at 2.85 m). Raises :class:`~distnav.errors.ModelError` when the
    problem is malformed or not determined (see the module docstring); ``check_determined=False`` skips the
    determinacy test (for :func:`distnav.models.uwb.geometry.check_geometry`, which finds the determined part).
    ``options``: :class:`ProblemOptions`, with keyword ``changes`` to it (:func:`distnav._settings.resolve_options`).
    """
    o = resolve_options(ProblemOptions, options, changes)
    dim, truth_m, initial_m = o.dim, o.truth_m, o.initial_m
    ids_t = _checked_ids(ids, dim)
    n = len(ids_t)
    index = {s: i for i, s in enumerate(ids_t)}
    a, b, r = _sample_ends(links, range_m, ids_t, index)
    positions, free = _known_coordinates(n, dim, index, o.fixed, o.held)
    fixed_mask = np.asarray(~free.any(axis=1))
    if o.check_determined:
        _check_determined(ids_t, dim, positions, free, fixed_mask, a, b)
    truth = _check_positions(truth_m, n, dim, "truth", ids_t) if truth_m is not None else None
    init = None
    if initial_m is not None:
        init = _check_positions(initial_m, n, dim, "initial guess", ids_t)
        init = np.where(free, init, positions)
    return RangingProblem(
        ids=ids_t,
        dim=dim,
        positions_m=positions,
        free=free,
        meas_a=a,
        meas_b=b,
        range_m=r,
        truth_m=truth,
        initial_m=init,
        name=o.name,
        info=dict(o.info or {}),
    )


def _checked_ids(ids: Sequence[str], dim: int) -> tuple[str, ...]:
    """The anchor ids as strings (ModelError: a dimension other than 2 or 3, fewer than 2 anchors, an id twice)."""
    ids_t = tuple(str(s) for s in ids)
    n = len(ids_t)
    if dim not in (2, 3):
        raise ModelError(f"dim must be 2 or 3, got {dim}")
    if n < 2:
        raise ModelError(f"a ranging problem needs at least 2 anchors, got {n}")
    if len(set(ids_t)) != n:
        seen: set[str] = set()
        dup = next(s for s in ids_t if s in seen or seen.add(s))  # type: ignore[func-returns-value]
        raise ModelError(f"anchor id {dup!r} is used twice")
    return ids_t


def _sample_ends(
    links: Sequence[tuple[Any, Any]] | np.ndarray,
    range_m: Sequence[float] | np.ndarray,
    ids_t: tuple[str, ...],
    index: dict[str, int],
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(a, b, range_m)`` of every sample, its ends by index (ModelError naming the sample: an unknown anchor, a
    self-range, a count mismatch, no ranges, a bad range)."""
    n = len(ids_t)

    def idx(v: Any, k: int) -> int:
        if isinstance(v, (int, np.integer)) and not isinstance(v, bool):
            if not 0 <= int(v) < n:
                raise ModelError(f"range #{k} names anchor index {v}, outside 0..{n - 1}")
            return int(v)
        s = str(v)
        if s not in index:
            raise ModelError(f"range #{k} names anchor {s!r}, which is not among the {n} anchors")
        return index[s]

    link_list = list(links) if not isinstance(links, np.ndarray) else links.tolist()
    r = real_array(range_m, "range_m", error=ModelError).ravel()
    if len(link_list) != r.size:
        raise ModelError(f"got {len(link_list)} links but {r.size} ranges")
    if r.size == 0:
        raise ModelError("no ranges: nothing to estimate from")
    a = np.array([idx(lk[0], k) for k, lk in enumerate(link_list)], np.int64)
    b = np.array([idx(lk[1], k) for k, lk in enumerate(link_list)], np.int64)
    same = a == b
    if same.any():
        k = int(np.argmax(same))
        raise ModelError(f"range #{k} joins anchor {ids_t[a[k]]!r} to itself")
    _check_ranges(r, a, b, ids_t)
    return a, b, r


def _known_coordinates(
    n: int,
    dim: int,
    index: dict[str, int],
    fixed: Mapping[str, Any] | None,
    held: Mapping[str, Mapping[int, float]] | None,
) -> tuple[np.ndarray, np.ndarray]:
    """``(positions, free)``: the fixed anchors' positions and the held coordinates, and which are free."""
    positions = np.zeros((n, dim))
    free = np.ones((n, dim), bool)
    for key, pos in (fixed or {}).items():
        if str(key) not in index:
            raise ModelError(f"fixed anchor {key!r} is not among the anchors")
        p = np.asarray(pos, float).ravel()
        if p.shape != (dim,) or not np.all(np.isfinite(p)):
            raise ModelError(f"fixed anchor {key!r} needs {dim} finite coordinates, got {pos!r}")
        positions[index[str(key)]] = p
        free[index[str(key)]] = False
    for key, axes in (held or {}).items():
        if str(key) not in index:
            raise ModelError(f"held coordinate of anchor {key!r}, which is not among the anchors")
        for ax, val in axes.items():
            if not 0 <= int(ax) < dim or not np.isfinite(float(val)):
                raise ModelError(f"held coordinate {ax}={val!r} of anchor {key!r} is invalid")
            positions[index[str(key)], int(ax)] = float(val)
            free[index[str(key)], int(ax)] = False
    return positions, free


def _check_determined(
    ids: tuple[str, ...],
    dim: int,
    positions: np.ndarray,
    free: np.ndarray,
    fixed_mask: np.ndarray,
    a: np.ndarray,
    b: np.ndarray,
) -> None:
    n = len(ids)
    n_fixed = int(fixed_mask.sum())
    heights_held = dim == 3 and bool(np.all(~free[~fixed_mask, 2]))
    planar_gauge = dim == 2 or heights_held
    need = 2 if planar_gauge else 3
    fpos = positions[fixed_mask]
    if n_fixed < need:
        what = (
            "2 fixed anchors (2-D, or 3-D with every height held)"
            if planar_gauge
            else "3 non-collinear fixed anchors in 3-D"
        )
        raise ModelError(f"the problem is not determined: it needs at least {what}, got {n_fixed}")
    if planar_gauge:
        spread = np.ptp(fpos[:, :2], axis=0).max()
        if spread <= 1e-9:
            raise ModelError("the problem is not determined: the fixed anchors coincide horizontally")
    elif _collinear(fpos):
        raise ModelError(
            f"the problem is not determined: the {n_fixed} fixed anchors "
            f"({', '.join(ids[i] for i in np.flatnonzero(fixed_mask)[:6])}) are collinear; 3-D needs 3 non-collinear"
        )
    adj = sp.csr_matrix((np.ones(a.size), (a, b)), shape=(n, n))
    _, labels = connected_components(adj, directed=False)
    anchored = np.isin(labels, labels[fixed_mask])
    lost = np.flatnonzero(~anchored & free.any(axis=1))
    if lost.size:
        shown = ", ".join(repr(ids[i]) for i in lost[:12])
        more = f" and {lost.size - 12} more" if lost.size > 12 else ""
        raise ModelError(
            f"the problem is not determined: estimated anchors {shown}{more} have no chain of measured links "
            f"to any fixed anchor"
        )


# ---------------------------------------------------------------------- generators (paper 002 §4)
def generate_layout(
    cls: str,
    rng: np.random.Generator | None = None,
    *,
    n_anchors: int = 100,
    spacing_m: float = 10.0,
    range_limit_m: float = 18.0,
    max_tries: int = 200,
) -> tuple[np.ndarray, np.ndarray]:
    """True 2-D anchor positions and measured links of class G, L or R (paper 002 §4, Fig. 2).

    G: a square grid (``√n × √n``) with ``spacing_m`` spacing, links to the 8 nearest (horizontal, vertical,
    diagonal) neighbours. L: a two-row ladder (``2 × n/2``), the same 8-neighbourhood rule, hence degree ≤ 5.
    R: ``n`` anchors uniform in a square of side ``spacing_m·√n`` (the grid's density), linked when closer than
    ``range_limit_m``; redrawn until connected (needs ``rng``).
    """
    n_anchors = whole_number(n_anchors, "n_anchors", minimum=1, error=ModelError)
    affordable_nodes(n_anchors, "a layout", error=ModelError, items="anchors")
    spacing_m = real_number(spacing_m, "spacing_m", positive=True, unit="m", error=ModelError)
    range_limit_m = real_number(range_limit_m, "range_limit_m", positive=True, unit="m", error=ModelError)
    max_tries = whole_number(max_tries, "max_tries", minimum=1, error=ModelError)
    cls = cls.upper()
    if cls in ("G", "L"):
        if cls == "G":
            side = int(round(np.sqrt(n_anchors)))
            if side * side != n_anchors:
                raise ModelError(f"class G needs a square number of anchors, got {n_anchors}")
            rows, cols = side, side
        else:
            if n_anchors % 2 or n_anchors < 4:
                raise ModelError(f"class L needs an even number ≥ 4 of anchors, got {n_anchors}")
            rows, cols = 2, n_anchors // 2
        idx = np.arange(rows * cols).reshape(rows, cols)
        parts = [
            np.stack([idx[:, :-1].ravel(), idx[:, 1:].ravel()], 1),
            np.stack([idx[:-1, :].ravel(), idx[1:, :].ravel()], 1),
            np.stack([idx[:-1, :-1].ravel(), idx[1:, 1:].ravel()], 1),
            np.stack([idx[:-1, 1:].ravel(), idx[1:, :-1].ravel()], 1),
        ]
        rr, cc = np.divmod(np.arange(rows * cols), cols)
        pos = np.stack([cc * spacing_m, rr * spacing_m], 1).astype(float)
        links = np.concatenate(parts)
        return pos, links[np.lexsort((links[:, 1], links[:, 0]))]
    if cls == "R":
        if rng is None:
            raise ModelError("class R needs a random generator")
        side = spacing_m * np.sqrt(n_anchors)
        from scipy.spatial import cKDTree

        for _ in range(max_tries):
            pos = rng.uniform(0.0, side, size=(n_anchors, 2))
            pairs = cKDTree(pos).query_pairs(range_limit_m, output_type="ndarray")
            adj = sp.csr_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(n_anchors, n_anchors))
            ncomp, _ = connected_components(adj, directed=False)
            if ncomp == 1:
                pairs = np.sort(pairs, axis=1)
                return pos, pairs[np.lexsort((pairs[:, 1], pairs[:, 0]))]
        raise ModelError(f"no connected class-R layout in {max_tries} draws")
    raise ModelError(f"unknown problem class {cls!r}; choose G, L or R")


def _nearest_noncollinear(pos: np.ndarray, target: np.ndarray, count: int, chosen: list[int]) -> list[int]:
    d = np.linalg.norm(pos - target, axis=1)
    order = np.lexsort((np.arange(pos.shape[0]), np.round(d, 9)))
    out = list(chosen)
    for i in order:
        if len(out) - len(chosen) == count:
            break
        if int(i) in out:
            continue
        trial = out + [int(i)]
        if len(trial) >= 3 and _collinear(pos[trial]):
            continue
        out.append(int(i))
    return out[len(chosen) :]


def select_fixed(pos: np.ndarray, selection: str, n_fixed: int = 3) -> np.ndarray:
    """Indices of the fixed anchors: C = the ``n_fixed`` anchors nearest the lower-left corner; O = two nearest
    the lower-right corner and one nearest the upper-left (paper 002 §4: "two in the bottom-right and one in
    the upper-left corner"); M = the anchors nearest the centroid. Chosen so they are never collinear."""
    p = np.asarray(pos, float)[:, :2]
    n_fixed = whole_number(n_fixed, "n_fixed", minimum=2 if selection.upper() == "O" else 1, error=ModelError)
    if n_fixed > p.shape[0]:
        raise ModelError(f"n_fixed={n_fixed} fixed anchors asked for among {p.shape[0]} anchors")
    lo, hi = p.min(axis=0), p.max(axis=0)
    sel = selection.upper()
    if sel == "C":
        out = _nearest_noncollinear(p, lo, n_fixed, [])
    elif sel == "O":
        first = _nearest_noncollinear(p, np.array([hi[0], lo[1]]), n_fixed - 1, [])
        out = first + _nearest_noncollinear(p, np.array([lo[0], hi[1]]), 1, first)
    elif sel == "M":
        out = _nearest_noncollinear(p, p.mean(axis=0), n_fixed, [])
    else:
        raise ModelError(f"unknown fixed-anchor selection {selection!r}; choose C, O or M")
    return np.array(sorted(out), np.int64)


@dataclass(frozen=True, kw_only=True)
class PaperProblemOptions:
    """The settings of :func:`generate_problem` (paper 002 §4): ``n_anchors`` (100), ``n_fixed`` (3),
    ``spacing_m`` (10 m), ``range_limit_m`` (18 m), ``sigma_m`` (0.15 m, the ranges' noise), ``init_halfwidth_m``
    (5 m), ``dim`` (3), ``layout`` (None: a new placement) and ``hold_heights`` (False)."""

    n_anchors: int = 100
    n_fixed: int = 3
    spacing_m: float = 10.0
    range_limit_m: float = 18.0
    sigma_m: float = 0.15
    init_halfwidth_m: float = 5.0
    dim: int = 3
    layout: tuple[np.ndarray, np.ndarray] | None = None
    hold_heights: bool = False

    def __post_init__(self) -> None:
        check_field_types(self, error=ModelError)  # types first, naming the field (issue 29)
        if self.sigma_m < 0 or self.init_halfwidth_m < 0:
            raise ModelError("sigma_m and init_halfwidth_m must be ≥ 0")
        if self.dim not in (2, 3):
            raise ModelError(f"dim must be 2 or 3, got {self.dim}")


def generate_problem(
    problem: str,
    rng: np.random.Generator,
    *,
    options: PaperProblemOptions | None = None,
    **changes: Any,
) -> RangingProblem:
    """One seeded instance of a paper problem such as ``"GC"`` (class letter + fixed-anchor selection).

    Ranges: true distance + ``N(0, sigma_m²)`` (one sample per link); initial guess: truth +
    ``U(−init_halfwidth_m, init_halfwidth_m)`` per coordinate of every estimated anchor (paper 002 eq. (23)).
    ``layout`` (positions, links) reuses a placement: the paper keeps the G and L placements over instances,
    and draws a new R placement for each instance. Anchors lie at z = 0 and are solved in ``dim`` = 3;
    ``hold_heights=True`` holds every estimated anchor's height at its true value (the paper's suggested height
    constraint), leaving the horizontal coordinates to estimate (the random draws are the same either way).
    ``options``: :class:`PaperProblemOptions`, with keyword ``changes`` to it.
    """
    name = problem.upper()
    if len(name) != 2 or name[0] not in PROBLEM_CLASSES or name[1] not in SELECTIONS[name[0]]:
        raise ModelError(f"unknown problem {problem!r}; choose one of {', '.join(PAPER_PROBLEMS)}")
    o = resolve_options(PaperProblemOptions, options, changes)
    n_anchors, spacing_m, range_limit_m, layout = o.n_anchors, o.spacing_m, o.range_limit_m, o.layout
    sigma_m, init_halfwidth_m, dim = o.sigma_m, o.init_halfwidth_m, o.dim
    pos2, links = (
        layout
        if layout is not None
        else generate_layout(name[0], rng, n_anchors=n_anchors, spacing_m=spacing_m, range_limit_m=range_limit_m)
    )
    n = pos2.shape[0]
    truth = np.zeros((n, dim))
    truth[:, :2] = pos2[:, :2]
    fixed_idx = select_fixed(pos2, name[1], o.n_fixed)
    a, b = links[:, 0], links[:, 1]
    true_d = np.linalg.norm(truth[a] - truth[b], axis=1)
    ranges = np.abs(true_d + rng.normal(0.0, sigma_m, size=true_d.size))
    init = truth + rng.uniform(-init_halfwidth_m, init_halfwidth_m, size=truth.shape)
    ids = [str(i) for i in range(n)]
    held = None
    if o.hold_heights:
        if dim != 3:
            raise ModelError("hold_heights needs dim=3")
        held = {ids[i]: {2: float(truth[i, 2])} for i in range(n) if i not in set(fixed_idx.tolist())}
    return build_problem(
        ids,
        np.stack([a, b], 1),
        ranges,
        fixed={ids[i]: truth[i] for i in fixed_idx},
        dim=dim,
        held=held,
        initial_m=init,
        truth_m=truth,
        name=name,
        info={"class": name[0], "selection": name[1], "sigma_m": sigma_m, "fixed": fixed_idx.tolist()},
    )
