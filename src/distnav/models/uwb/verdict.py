"""The run's answer to an installer: is this anchor map good enough to position tags at the accuracy I need?
(issue 28, item 2).

Per anchor (``positions.csv`` keeps its status: known / estimated / weak with a reason / ambiguous / unsolved) an
**accuracy radius** ``accuracy_m = k · √(σx² + σy² [+ σz²])`` (the a-posteriori σ the solve reports): the radius
that holds the anchor's error with probability ``1 − (1 − JOINT_CONFIDENCE) / n`` if its error is Gaussian with
that covariance (``k² = χ²_q`` quantile, ``q`` its free coordinates, ``n`` the estimated anchors), so that every
anchor lies within its radius **jointly** with probability ≥ ``JOINT_CONFIDENCE`` (0.99; Bonferroni; the trace
bounds the largest eigenvalue, so the radius is conservative for an elongated ellipse). An anchor **meets** the
required accuracy when it is estimated (not weak, ambiguous or unsolved; a weak anchor's σ do not cover what may
be wrong with it — except a ``thin`` one whose worst undetected-link shift, from the external reliability test, is
within the required accuracy) and its radius is at most ``required_accuracy_m``, and its position does not rest on
a doubtful fit (:func:`fit_doubts`; issue 28's open defect, a plant-like hall whose fit was the mirror image with two
anchors "meeting" 0.3 m while 6–10 m off):

* **half or more of its links excluded** (:data:`MAX_ANCHOR_EXCLUDED_SHARE`): the kept links are no majority, so
  which of them are NLOS was the fit's choice rather than the data's (the breakdown point of a robust fit);
* **its kept links misfit beyond their χ² expectation**: ``Σ (e_l / σ̂)²`` over its kept links (``σ̂`` the network's
  robust residual scale, 1.4826 × the median |e| of the kept links) above the ``χ²_n`` quantile at
  :data:`CHI2_LEVEL` / (number of estimated anchors) — the residuals of a fitted anchor are smaller than the errors,
  so under the model this fails an anchor with probability below that level; a larger sum means links the
  exclusions left in that the fit does not explain.

On 100 plant-like halls (``bench_uwb_verdict.py``'s and a second stream of seeds) the two rules took 7 of the 1,631
anchors that met 0.3 m (1 by its excluded share, 6 by χ²; all within 0.05 m of the truth: the price of the rules),
no run's exit code changed, and the χ² rule also holds 7 of the 23 anchors truly off by more than 0.3 m (which fail
for other reasons first). They do not see the mirror-image fit of issue 28's hall (its kept links fitted to 1.9 cm,
1 of 9 and 1 of 13 links excluded at the two anchors that "met" 0.3 m): the initial search's ``handedness`` start
(:mod:`distnav.models.uwb.initial`) is what fixed that hall.

The run (exit code of ``uwb solve``):

* ``ok`` (exit 0, status ``converged`` / ``max_iterations``): every anchor meets the required accuracy;
* ``unusable`` (exit 1): nothing solved (``diverged``, no positions written) or data inconsistent with the
  model: more than :data:`MAX_EXCLUDED_SHARE` of the links excluded as NLOS (a heavily corrupted log: 30 % of the
  links +5 m excludes 30–42 % on simulated plant halls, a clean one 7–14 %), every anchor weak because the
  exclusions and the robust fit of every link disagree, or an a-posteriori variance factor above
  :data:`MAX_VARIANCE_FACTOR` (range errors over 5 × ``--sigma-m``); positions are written for diagnosis, status
  ``weakly_determined``;
* ``not_accurate`` (exit 3, status ``weakly_determined``): a usable map, but the listed anchors do not meet the
  required accuracy (and why: weak, radius, unsolved, …);
* ``ambiguous`` (exit 4): the ranges cannot tell the network from its mirror image (``positions_mirror.csv``
  holds the other map) or an anchor from its flip;
* exit 2 is bad input or a refused geometry (the CLI's rule).
"""

from __future__ import annotations

import dataclasses
import itertools
from typing import Any

import numpy as np
from scipy import special

from distnav.algorithms.ranging.qc import robust_scale
from distnav.models.uwb.field import FieldSolution
from distnav.models.uwb.local import fit_anchor
from distnav.typing import FloatArray

__all__ = [
    "EXIT_AMBIGUOUS",
    "EXIT_NOT_ACCURATE",
    "EXIT_OK",
    "EXIT_UNUSABLE",
    "JOINT_CONFIDENCE",
    "CHI2_LEVEL",
    "MAX_ANCHOR_EXCLUDED_SHARE",
    "MAX_EXCLUDED_SHARE",
    "MAX_VARIANCE_FACTOR",
    "REQUIRED_ACCURACY_M",
    "RunVerdict",
    "accuracy_radius_m",
    "alternative_links",
    "fit_doubts",
    "run_verdict",
]

REQUIRED_ACCURACY_M = 0.3  # what UWB tag positioning is usually asked for (decimetres): an anchor worse spoils it
JOINT_CONFIDENCE = 0.99
MAX_EXCLUDED_SHARE = 0.25
MAX_VARIANCE_FACTOR = 25.0
MAX_ANCHOR_EXCLUDED_SHARE = 0.5  # an anchor with at least this share of its links excluded is not certified
CHI2_LEVEL = 0.001  # the per-anchor χ² check's level (the link tests' default), Bonferroni over the anchors
EXIT_OK, EXIT_UNUSABLE, EXIT_NOT_ACCURATE, EXIT_AMBIGUOUS = 0, 1, 3, 4
_RADIUS = "accuracy radius"  # the reason of an anchor that fails by its radius alone


@dataclasses.dataclass(frozen=True)
class RunVerdict:
    """What :func:`run_verdict` decided: ``verdict`` (ok / not_accurate / unusable / ambiguous), ``exit_code``,
    the run ``status``, the required accuracy, each estimated anchor's accuracy radius, the anchors that do not
    meet it (``failing``: id → why) and the run-level ``reasons`` of an unusable or ambiguous map."""

    verdict: str
    exit_code: int
    status: str
    required_accuracy_m: float
    accuracy_m: dict[str, float]
    failing: dict[str, str]
    reasons: tuple[str, ...] = ()

    @property
    def blocking(self) -> tuple[str, ...]:
        """The failing anchors that no required accuracy would let pass: weak, ambiguous, unsolved, a geometry
        issue or no σ (their σ do not cover what may be wrong with them; the remedy is more links or a known
        anchor near them, docs/uwb.md)."""
        return tuple(k for k, why in self.failing.items() if not why.startswith(_RADIUS))

    @property
    def map_accuracy_m(self) -> float | None:
        """The accuracy the map meets apart from :attr:`blocking`: the largest accuracy radius among the other
        estimated anchors (``--required-accuracy-m`` at or above it passes them all; None if none is left)."""
        rest = [v for k, v in self.accuracy_m.items() if k not in self.blocking and np.isfinite(v)]
        return max(rest) if rest else None

    def as_dict(self) -> dict[str, Any]:
        return {**dataclasses.asdict(self), "map_accuracy_m": self.map_accuracy_m, "blocking": list(self.blocking)}


def accuracy_radius_m(sigma_m: FloatArray, free: np.ndarray, *, confidence: float = JOINT_CONFIDENCE) -> FloatArray:
    """Per anchor, the radius of the module docstring (0 for an anchor without a free coordinate, NaN where a σ of
    a free coordinate is unknown)."""
    s = np.where(free, np.asarray(sigma_m, float), 0.0)
    q = free.sum(axis=1)
    n = max(int((q > 0).sum()), 1)
    alpha = (1.0 - confidence) / n
    k = np.sqrt(np.where(q > 0, special.chdtri(np.maximum(q, 1), alpha), 0.0))
    out: FloatArray = k * np.sqrt(np.sum(s**2, axis=1))
    return out


def _thin_but_reliable(sol: FieldSolution, name: str, required_accuracy_m: float) -> bool:
    """A ``thin`` anchor (one redundant link: one NLOS link there could go unseen) whose external reliability was
    tested and whose worst undetected-link shift (Baarda's MDB carried to its position) is within the required
    accuracy: the risk ``thin`` warns of is bounded, so the anchor is judged by its radius like any other."""
    shift = (sol.reliability or {}).get("shift_m", {}).get(name, None)
    reason = sol.weak_reasons.get(name, "")
    return reason.startswith("thin") and shift is not None and shift <= required_accuracy_m


def fit_doubts(sol: FieldSolution) -> dict[str, str]:
    """The estimated anchors whose position rests on a doubtful fit (module docstring), each with its reason."""
    p = sol.problem
    kept = ~np.asarray(sol.excluded, bool)
    e = np.asarray(sol.residual_m, float)
    ok = kept & np.isfinite(e)
    n = p.n_anchors
    a, b = p.meas_a, p.meas_b
    links = np.bincount(a, minlength=n) + np.bincount(b, minlength=n)
    out_n = np.bincount(a[~kept], minlength=n) + np.bincount(b[~kept], minlength=n)
    scale = robust_scale(e[ok]) if ok.any() else float("nan")
    z2 = np.where(ok, (e / scale) ** 2 if scale > 0 else 0.0, 0.0)
    chi2 = np.bincount(a, z2, minlength=n) + np.bincount(b, z2, minlength=n)
    n_kept = np.bincount(a[ok], minlength=n) + np.bincount(b[ok], minlength=n)
    est = np.flatnonzero(p.estimated)
    alpha = CHI2_LEVEL / max(est.size, 1)
    out: dict[str, str] = {}
    for i in est:
        if links[i] and out_n[i] / links[i] >= MAX_ANCHOR_EXCLUDED_SHARE:
            out[p.ids[i]] = (
                f"excluded: {int(out_n[i])} of its {int(links[i])} links excluded as NLOS (half or more: the fit "
                "chose which are)"
            )
        elif n_kept[i] and np.isfinite(scale) and scale > 0:
            q = float(special.chdtri(n_kept[i], alpha))
            if chi2[i] > q:
                out[p.ids[i]] = (
                    f"misfit: its {int(n_kept[i])} kept links' Σ(e/σ̂)² = {chi2[i]:.3g} > {q:.3g}, the χ² quantile "
                    f"at {alpha:.2g} (σ̂ = {scale:.3g} m, the network's robust residual scale)"
                )
    return out


MAX_SUBSETS = 2000  # link subsets tried per anchor by alternative_links (C(12, 6) = 924)


def alternative_links(sol: FieldSolution, i: int, required_accuracy_m: float) -> str | None:
    """Why anchor ``i``'s position is one of two the ranges allow, or None: with two or more of its links excluded,
    another set of as many of its links as it kept fits it as well (its own position fitted with the neighbours
    held, :func:`~distnav.models.uwb.local.fit_anchor`, RMS within 3σ̂, the network's robust residual scale of the
    kept links) at a point more than ``required_accuracy_m`` away, and every link that set leaves out reads long
    there by more than 3σ̂ (as an NLOS link does). The same number of NLOS links explains the ranges either way:
    which set is NLOS is the fit's choice, not the data's (issue 28: a plant-like hall whose anchor kept its 3 NLOS
    links of 7 and excluded 3 good ones, 1.84 m off with σ 0.05 m, certified)."""
    p = sol.problem
    mine = np.flatnonzero((p.meas_a == i) | (p.meas_b == i))
    out = np.asarray(sol.excluded, bool)[mine]
    k = int((~out).sum())
    if out.sum() < 2 or k <= int(p.free[i].sum()) or special.comb(mine.size, k) > MAX_SUBSETS:
        return None
    pos = np.asarray(sol.positions_m, float)
    bias = np.asarray(sol.residual_m, float) - p.residuals_m(pos)  # the solution's range offsets, per link
    q = p.with_ranges(p.range_m - np.nan_to_num(bias))
    e = np.asarray(sol.residual_m, float)[~np.asarray(sol.excluded, bool)]
    tol = 3.0 * robust_scale(e[np.isfinite(e)])
    if not (np.isfinite(tol) and tol > 0):
        return None
    current = set(mine[~out].tolist())
    for subset in itertools.combinations(mine.tolist(), k):
        if set(subset) == current:
            continue
        at, rms = fit_anchor(q, i, pos, list(subset))
        moved = float(np.linalg.norm(at - pos[i]))
        if rms > tol or moved <= required_accuracy_m:
            continue
        left = np.array([m for m in mine if m not in subset])
        other = np.where(q.meas_a[left] == i, q.meas_b[left], q.meas_a[left])
        if np.all(np.linalg.norm(pos[other] - at, axis=1) - q.range_m[left] < -tol):
            names = ", ".join(f"{p.ids[p.meas_a[m]]}-{p.ids[p.meas_b[m]]}" for m in left)
            return (
                f"alternative: leaving out {names} instead (each read long there) fits it as well "
                f"(RMS {rms:.3f} m ≤ 3σ̂ = {tol:.3f} m), {moved:.2f} m away"
            )
    return None


def run_verdict(sol: FieldSolution, required_accuracy_m: float = REQUIRED_ACCURACY_M) -> RunVerdict:
    """The run's verdict (module docstring) for one solution of ``uwb solve``."""
    if not sol.usable:
        return RunVerdict("unusable", EXIT_UNUSABLE, sol.status, required_accuracy_m, {}, {}, (sol.message,))
    p = sol.problem
    radius = accuracy_radius_m(sol.sigma_m, p.free)
    amb = sol.geometry.ambiguous_anchors()
    geo_weak = {a: i.kind for i in sol.geometry.issues if i.severity == "weakly_determined" for a in i.anchors}
    doubts = fit_doubts(sol)
    accuracy: dict[str, float] = {}
    failing: dict[str, str] = {}
    for i in np.flatnonzero(p.estimated):
        name = p.ids[i]
        accuracy[name] = float(radius[i])
        if name in amb:
            failing[name] = "ambiguous"
        elif name in sol.weak and not _thin_but_reliable(sol, name, required_accuracy_m):
            failing[name] = "weak: " + sol.weak_reasons.get(name, "")
        elif name in geo_weak:
            failing[name] = f"geometry: {geo_weak[name]}"
        elif name in doubts:
            failing[name] = doubts[name]
        elif not np.isfinite(radius[i]):
            failing[name] = "no σ"
        elif radius[i] > required_accuracy_m:
            failing[name] = f"{_RADIUS} {radius[i]:.3f} m > {required_accuracy_m:g} m"
        elif alt := alternative_links(sol, int(i), required_accuracy_m):
            failing[name] = alt
    for name in sol.geometry.unsolved:
        failing[name] = "unsolved: the ranges cannot locate it"
    n_links = max(p.n_meas, 1)
    share = float(sol.excluded.sum()) / n_links
    vf = getattr(getattr(sol.result, "precision", None), "variance_factor", None)
    reasons: list[str] = []
    if share > MAX_EXCLUDED_SHARE:
        reasons.append(
            f"{int(sol.excluded.sum())} of {p.n_meas} links ({share:.0%}) excluded as NLOS, more than "
            f"{MAX_EXCLUDED_SHARE:.0%}: the log is corrupted or the anchors' ids / positions do not match it"
        )
    n_est = int(p.estimated.sum())
    disagree = [k for k, v in sol.weak_reasons.items() if v.startswith("disagree")]
    if n_est and len(disagree) == n_est:
        reasons.append("the exclusions and the robust fit of every link disagree: no consistent set of links")
    if vf is not None and np.isfinite(vf) and vf > MAX_VARIANCE_FACTOR:
        reasons.append(
            f"a-posteriori variance factor {vf:.3g} > {MAX_VARIANCE_FACTOR:g}: the ranges scatter more than 5 × "
            "the a-priori σ (--sigma-m)"
        )
    if sol.status == "ambiguous":
        return RunVerdict(
            "ambiguous", EXIT_AMBIGUOUS, "ambiguous", required_accuracy_m, accuracy, failing, tuple(reasons)
        )
    if reasons:
        return RunVerdict(
            "unusable", EXIT_UNUSABLE, "weakly_determined", required_accuracy_m, accuracy, failing, tuple(reasons)
        )
    if failing:
        return RunVerdict(
            "not_accurate", EXIT_NOT_ACCURATE, "weakly_determined", required_accuracy_m, accuracy, failing
        )
    status = sol.status if sol.status in ("converged", "max_iterations") else "converged"
    return RunVerdict("ok", EXIT_OK, status, required_accuracy_m, accuracy, failing)
