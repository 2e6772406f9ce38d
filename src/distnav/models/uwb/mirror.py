"""The mirror test of a network whose known anchors lie *nearly* on one line (issues 13 and 28).

Known anchors exactly on one line make a 2-D network (or a 3-D one with its heights held) ambiguous: its mirror
image through that line fits every range (:func:`~distnav.models.uwb.geometry.check_geometry`, ``mirror``).
Nearly on one line (``near_line``: line ratio below 0.1), the mirror image fits almost as well, and whether the
ranges can tell the two apart depends on their errors, not on the geometry alone (APRIL lab data with known nodes
8, 61, 12: node 12 is 0.13 m off their line and the two sides' costs differ by 0.6 %; issue 28: four known anchors
on one wall, within 2 cm of a line, cost differences of 0.2 %). So both sides are fitted for real and compared by a
test of stated power:

1. **Both sides fitted.** The workflow (:func:`~distnav.models.uwb.field.solve_field`) runs once as usual; its free
   anchors are reflected through the known anchors' best-fit line (horizontal coordinates) and the workflow runs
   again from there **without the multi-start** (its candidate starts are MDS starts aligned to the known anchors,
   which would take the fit back to whichever side the alignment chose: issue 28 found even ``--initial`` with the
   true positions ending in the mirror).
2. **Two tests, each at half the level** (two simple hypotheses, side A or side B):

   * **Gaussian** (Neyman–Pearson on the Gaussian likelihood). On the links kept by both fits, with ``d`` the
     difference of the two fits' predicted ranges and ``σ̂²`` the a-posteriori variance of the better fit,
     ``Δ = (Σ e_B² − Σ e_A²) / σ̂²`` (A: the lower sum) is about ``N(λ, 4λ)`` if A is true and ``N(−λ, 4λ)`` if B
     is, ``λ = Σ d² / σ̂²``. It chooses A when ``Δ > c = 2 z √λ − λ`` (``z = Φ⁻¹(1 − level/2)``, ``level`` the
     link tests' false-alarm probability, 0.001): if B were the truth, a difference that large would come with
     probability ``level/2`` at most. Its **power** — the probability of choosing when A is the truth — is
     ``Φ(√λ − z)`` and is reported. It sees only the links both fits kept, and each fit drops the links that
     contradict it (a mirror fit excluded 23–24 links against the true side's 6–17 on simulated walls), so on
     walls 0.2–1.5 m off the line its power was 0.23 (median λ 5.6) while the data held far more evidence.
   * **Robust** (the likelihood ratio of *all* the links). The one-sided Cauchy cost of every link
     (:func:`~distnav.models.uwb.field.all_links_cost`, excluded links too, at ``loss_scale_m`` ``s``) is, up to
     a constant, exactly the negative log-likelihood of the error model the workflow fits: a range read short by
     ``e`` has density ∝ ``exp(−(e/s)²)``, one read long ∝ ``1 / (1 + (e/s)²)``, one normalising constant for
     both branches. So ``D = cost_B − cost_A`` is the log-likelihood ratio, and by Markov's inequality
     (``E_B[L_A / L_B] = 1``) ``P_B(D ≥ T) ≤ exp(−T)`` whatever the geometry: with ``T = log(2 / level)`` a side
     is chosen wrongly with probability ``level/2`` at most (``tests/test_uwb_mirror.py`` checks the bound by
     Monte Carlo). On those walls ``D`` favoured the truth on 23 of 24 halls by 3.0–39.9, and was within 0.3 on
     all 25 walls within 2 cm of a line (where no test can choose: λ ≈ 0.3).

   A side is **chosen** when one test chooses it and the other does not choose the opposite side (a conflict is
   ambiguous: on simulated walls the Gaussian test alone would have chosen the mirror 3 times, each time against a
   robust ``D`` of 12–29 for the truth); the false choice has probability ≤ ``level`` (the union of the two).
   When the reflected fit lands back on the first solution (< :data:`MIRROR_DISTINCT_M` m RMS away) the mirror
   is no solution of the ranges and the side is chosen (λ small, nothing to compare).
3. **Ambiguous** when the test cannot choose (``Δ ≤ c``): status ``ambiguous`` (exit 4 in ``uwb solve``), the
   map with the lower robust cost of all the links (:func:`~distnav.models.uwb.field.all_links_cost`, the
   workflow's own order) written as ``positions.csv`` and the other as ``positions_mirror.csv``; never one of
   them alone with exit 0.

The distribution is that of two fixed solutions; the fits adapt to the noise, so it is an approximation (the
benchmark ``bench_uwb_stress.py`` counts how often the chosen side is wrong on simulated walls).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from typing import Any

import numpy as np
from scipy import special

from distnav.models.uwb.field import FieldOptions, FieldSolution, all_links_cost, solve_field
from distnav.models.uwb.geometry import GeometryIssue, GeometryReport
from distnav.models.uwb.problems import RangingProblem
from distnav.models.uwb.search import choose_handedness
from distnav.typing import FloatArray

__all__ = [
    "MIRROR_DISTINCT_M",
    "MirrorTest",
    "mirror_test",
    "reflect_through_known_line",
    "side_test",
    "solve_with_mirror_test",
]

MIRROR_DISTINCT_M = 0.5  # RMS distance under which the reflected fit came back to the first solution


@dataclasses.dataclass(frozen=True)
class MirrorTest:
    """The side tests of the module docstring: ``delta`` (Δ), ``critical`` (c), ``noncentrality`` (λ), ``power``,
    ``level`` (of the two tests together), ``chosen``, ``apart_m`` (RMS distance of the two maps), ``n_links`` (kept by
    both); ``robust_log_ratio`` (D = cost_B − cost_A, positive for A), ``robust_threshold`` (T), ``chosen_by``
    (``gaussian``, ``robust``, ``both``, ``same solution``; empty when not chosen)."""

    delta: float
    critical: float
    noncentrality: float
    power: float
    level: float
    chosen: bool
    apart_m: float
    n_links: int
    robust_log_ratio: float | None = None
    robust_threshold: float | None = None
    chosen_by: str = ""

    def as_dict(self) -> dict[str, Any]:
        return dataclasses.asdict(self)


def reflect_through_known_line(positions_m: FloatArray, fixed: np.ndarray, free: np.ndarray) -> FloatArray:
    """``positions_m`` with the free horizontal coordinates reflected through the best-fit line of the fixed
    anchors' horizontal positions (heights unchanged)."""
    p = np.array(positions_m, float)
    k = p[fixed][:, :2]
    c = k.mean(axis=0)
    _, _, vt = np.linalg.svd(k - c, full_matrices=False)
    n = vt[-1]  # unit normal of the line
    xy = p[:, :2] - c
    refl = p[:, :2] - 2.0 * np.outer(xy @ n, n)
    p[:, :2] = np.where(free[:, :2], refl, p[:, :2])
    return p


def mirror_test(best: FieldSolution, other: FieldSolution, level: float) -> MirrorTest:
    """The test of the module docstring between two usable solutions of one problem, ``best`` the one with the
    lower sum of squared residuals on the links both kept."""
    p = best.problem
    est = p.estimated
    apart_m = float(np.sqrt(np.mean(np.sum((best.positions_m[est] - other.positions_m[est]) ** 2, axis=1))))
    both = ~best.excluded & ~other.excluded & np.isfinite(best.residual_m) & np.isfinite(other.residual_m)
    n_unknown = int(p.free[est].sum()) + 1  # the positions and a common offset
    delta, critical, lam, power = side_test(best.residual_m[both], other.residual_m[both], n_unknown, level / 2)
    same = apart_m <= MIRROR_DISTINCT_M
    chosen = same or delta > critical
    by = "same solution" if same else ("gaussian" if chosen else "")
    return MirrorTest(delta, critical, lam, power, level, bool(chosen), apart_m, int(both.sum()), chosen_by=by)


def decide_side(test: MirrorTest, robust_a: float, robust_b: float) -> tuple[MirrorTest, bool]:
    """The combined decision of the module docstring from the Gaussian ``test`` (side A: the lower squared residuals)
    and the robust costs of all the links of A and B: ``(test with the decision, whether B is the chosen side)``."""
    d = robust_b - robust_a
    t = float(np.log(2.0 / test.level))
    rec = dataclasses.replace(test, robust_log_ratio=d, robust_threshold=t)
    if test.chosen_by == "same solution":
        return rec, False
    gauss_a, robust_a_wins, robust_b_wins = test.delta > test.critical, d > t, -d > t
    if robust_b_wins and not gauss_a:
        return dataclasses.replace(rec, chosen=True, chosen_by="robust"), True
    if (gauss_a or robust_a_wins) and not robust_b_wins:
        by = "both" if gauss_a and robust_a_wins else ("gaussian" if gauss_a else "robust")
        return dataclasses.replace(rec, chosen=True, chosen_by=by), False
    return dataclasses.replace(rec, chosen=False, chosen_by=""), False


def side_test(
    residual_a_m: FloatArray, residual_b_m: FloatArray, n_unknown: int, level: float
) -> tuple[float, float, float, float]:
    """``(Δ, c, λ, power)`` of the module docstring's test from the residuals (measured − predicted, metres) of the
    two solutions A (lower cost) and B on the same links; ``n_unknown`` sets the redundancy of σ̂²."""
    ea, eb = np.asarray(residual_a_m, float), np.asarray(residual_b_m, float)
    s2 = max(float(ea @ ea) / max(ea.size - n_unknown, 1), 1e-12)
    delta = float(eb @ eb - ea @ ea) / s2
    lam = float(np.sum((eb - ea) ** 2)) / s2  # e = measured − predicted: e_B − e_A is the difference d
    z = float(-special.ndtri(level))
    critical = float(max(2.0 * z * np.sqrt(lam) - lam, 0.0))
    power = float(special.ndtr(np.sqrt(lam) - z))
    return delta, critical, lam, power


def solve_with_mirror_test(
    problem: RangingProblem, opts: FieldOptions, geometry: GeometryReport, exchange: Callable[[Any], Any] | None = None
) -> FieldSolution:
    """:func:`~distnav.models.uwb.field.solve_field` (a distributed solver from the start of the better handedness,
    :func:`~distnav.models.uwb.search.choose_handedness`), plus the mirror test of the module docstring where
    ``geometry`` has a ``near_line`` issue (both fits are then made without it; kept only when no test is made)."""
    problem, start_note = choose_handedness(problem, opts)
    near = [i for i in geometry.issues if i.kind == "near_line"]
    if not near:
        sol = solve_field(problem, opts, geometry=geometry, exchange=exchange)
        return dataclasses.replace(sol, message=sol.message + start_note) if start_note else sol
    rest = tuple(i for i in geometry.issues if i.kind != "near_line")
    plain = dataclasses.replace(geometry, issues=rest)
    sol = solve_field(problem, opts, geometry=plain, exchange=exchange)
    if not sol.usable:
        return dataclasses.replace(sol, geometry=geometry)
    start = reflect_through_known_line(sol.positions_m, problem.fixed, problem.free)
    other = solve_field(
        problem.with_initial(start), dataclasses.replace(opts, multi_start=False), geometry=plain, exchange=exchange
    )
    line = near[0].message.split(":")[0]
    if not other.usable:
        return dataclasses.replace(
            sol,
            geometry=geometry,
            status="ambiguous",
            message=f"ambiguous: {near[0].message} (the fit from the mirror image diverged: no test) — {sol.message}",
        )
    ssr = [float(np.sum(s.residual_m[~sol.excluded & ~other.excluded] ** 2)) for s in (sol, other)]
    best, alt = (sol, other) if ssr[0] <= ssr[1] else (other, sol)
    side_a = best
    robust = (all_links_cost(problem, best.result, opts), all_links_cost(problem, alt.result, opts))
    test, b_chosen = decide_side(mirror_test(best, alt, opts.level), *robust)
    costs = f"robust cost of all links {robust[0]:.4g} against {robust[1]:.4g}"
    if b_chosen or (not test.chosen and robust[1] < robust[0]):  # the robust test's side; ambiguous: positions.csv
        best, alt = alt, best  # gets the lower robust cost of all the links (the workflow's own order, NLOS-aware)
        costs = f"robust cost of all links {robust[1]:.4g} against {robust[0]:.4g}; squared residuals favour the other"
    record = {  # side A: the lower squared residuals (the test's A); which map positions.csv holds
        **test.as_dict(),
        "robust_cost_a": robust[0],
        "robust_cost_b": robust[1],
        "written_is_a": best is side_a,
    }
    best = dataclasses.replace(
        best,
        iterations=sol.iterations + other.iterations,
        messages=sol.messages + other.messages,
        bytes=sol.bytes + other.bytes,
        mirror=record,
    )  # both fits
    stats = (
        f"Δ = {test.delta:.3g} against the critical {test.critical:.3g} (λ = {test.noncentrality:.3g}, level "
        f"{test.level / 2:g}, power {test.power:.2f}, {test.n_links} links); robust log-likelihood ratio "
        f"{abs(test.robust_log_ratio or 0.0):.3g} against {test.robust_threshold or 0.0:.3g} (level {test.level / 2:g})"
        + (f"; chosen by {test.chosen_by}" if test.chosen_by else "")
    )
    if not test.chosen:
        issue = GeometryIssue(
            "mirror",
            "ambiguous",
            near[0].anchors,
            f"{line}: the fit started from the mirror image through that line lands {test.apart_m:.2f} m RMS away "
            f"and the ranges cannot tell the two apart ({stats}; {costs}): ambiguous — both maps are written "
            f"(positions.csv: the lower robust cost, positions_mirror.csv: its mirror); add a known anchor farther off "
            f"the line",
        )
        return dataclasses.replace(
            best,
            geometry=dataclasses.replace(geometry, issues=rest + (issue,)),
            status="ambiguous",
            message=f"ambiguous: {issue.message} — {best.message}",
            mirror_positions_m=alt.positions_m,
        )
    note = f"{line}: checked — " + (
        f"the fit started from the mirror image through that line returns to the same solution "
        f"({test.apart_m:.2f} m RMS): the mirror is no solution of the ranges"
        if test.apart_m <= MIRROR_DISTINCT_M
        else f"both sides fitted ({test.apart_m:.2f} m RMS apart); the ranges choose this side: {stats}; {costs}"
    )
    return dataclasses.replace(best, geometry=dataclasses.replace(plain, notes=plain.notes + (note,)))
