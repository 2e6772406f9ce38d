"""The mirror test of a network whose known anchors lie *nearly* on one line (issue 13, item 4).

Known anchors exactly on one line make a 2-D network (or a 3-D one with its heights held) ambiguous: its mirror
image through that line fits every range (:func:`~distnav.models.uwb.geometry.check_geometry`, ``mirror``).
Nearly on one line (``near_line``: line ratio below 0.1), the mirror image fits almost as well, and whether the
ranges can still tell the two apart_m depends on their errors, not on the geometry alone:

* APRIL lab data (real DW1000 ranges, scatter 0.2–0.3 m) with known nodes 8, 61, 12 — node 12 is 0.13 m off
  the best-fit line of the three: the mirror image fits the ranges *better* (Cauchy cost of all links 84 against
  108 near the truth) and LM returns it, 4.1 m RMSE, as ``converged``;
* simulated halls with the known anchors along one wall (0.2–1.5 m off their line, 5 cm noise): the true side
  fits clearly better and distnav is within 1.4× the oracle (``benchmarks/bench_uwb_stress.py``).

So the test is made on the data: the solution's free anchors are reflected through the known anchors' best-fit
line (horizontal coordinates), the same workflow (:func:`~distnav.models.uwb.field.solve_field`) is re-run from
there, and the two solutions are compared by the robust cost of *all* links
(:func:`~distnav.models.uwb.field.all_links_cost`). If the mirrored fit lands on a different solution (more
than ``MIRROR_DISTINCT_M`` RMS away) whose cost is below ``MIRROR_COST_RATIO`` × the other's, the network is
**ambiguous** (issue ``mirror``, exit 1 in ``uwb solve``) and the lower-cost solution is reported; otherwise the
``near_line`` warning is replaced by a note of the costs (the ranges chose the side). One more solve, only when
the known anchors are nearly collinear (its messages and bytes, for a distributed solver, are added to the
reported ones).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from typing import Any

import numpy as np

from distnav.models.uwb.field import FieldOptions, FieldSolution, all_links_cost, solve_field
from distnav.models.uwb.geometry import GeometryIssue, GeometryReport
from distnav.models.uwb.problems import RangingProblem
from distnav.typing import FloatArray

__all__ = ["MIRROR_COST_RATIO", "MIRROR_DISTINCT_M", "reflect_through_known_line", "solve_with_mirror_test"]

MIRROR_COST_RATIO = 1.5  # the ratio FieldOptions' revert uses to call two solutions' fits of all links different
MIRROR_DISTINCT_M = 0.5


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


def solve_with_mirror_test(
    problem: RangingProblem, opts: FieldOptions, geometry: GeometryReport, exchange: Callable[[Any], Any] | None = None
) -> FieldSolution:
    """:func:`~distnav.models.uwb.field.solve_field`, plus the mirror test of the module docstring where
    ``geometry`` has a ``near_line`` issue (both fits are then made without it; it is kept, weakly determined,
    only when the test cannot be made)."""
    near = [i for i in geometry.issues if i.kind == "near_line"]
    if not near:
        return solve_field(problem, opts, geometry=geometry, exchange=exchange)
    rest = tuple(i for i in geometry.issues if i.kind != "near_line")
    plain = dataclasses.replace(geometry, issues=rest)
    sol = solve_field(problem, opts, geometry=plain, exchange=exchange)
    if not sol.usable:
        return dataclasses.replace(sol, geometry=geometry)
    start = reflect_through_known_line(sol.positions_m, problem.fixed, problem.free)
    other = solve_field(problem.with_initial(start), opts, geometry=plain, exchange=exchange)
    line = near[0].message.split(":")[0]
    if not other.usable:
        weak = "weakly_determined" if sol.status in ("converged", "max_iterations") else sol.status
        return dataclasses.replace(
            sol,
            geometry=geometry,
            status=weak,
            message=f"{weak}: {near[0].message} (the mirror test diverged) — {sol.message}",
        )
    c0 = all_links_cost(problem, sol.result, opts)
    c1 = all_links_cost(problem, other.result, opts)
    est = problem.estimated
    apart_m = float(np.sqrt(np.mean(np.sum((sol.positions_m[est] - other.positions_m[est]) ** 2, axis=1))))
    best, cb, cw = (sol, c0, c1) if c0 <= c1 else (other, c1, c0)
    best = dataclasses.replace(
        best,
        iterations=sol.iterations + other.iterations,
        messages=sol.messages + other.messages,
        bytes=sol.bytes + other.bytes,
    )  # both fits
    if apart_m > MIRROR_DISTINCT_M and cw < MIRROR_COST_RATIO * cb:
        issue = GeometryIssue(
            "mirror",
            "ambiguous",
            near[0].anchors,
            f"{line}: the fit started from the mirror image through that line lands {apart_m:.2f} m RMS away and fits "
            f"all the links about as well (robust cost {cw:.1f} against {cb:.1f}, < {MIRROR_COST_RATIO:g}×): the "
            f"ranges cannot tell the network from its mirror image (ambiguous; the lower-cost one is reported); add "
            f"a known anchor farther off the line",
        )
        return dataclasses.replace(
            best,
            geometry=dataclasses.replace(geometry, issues=rest + (issue,)),
            status="ambiguous",
            message=f"ambiguous: {issue.message} — {best.message}",
        )
    note = (
        f"{line}: checked — the fit started from the mirror image through that line "
        + (
            f"fits all the links {cw / cb:.2f}× worse (robust cost {cw:.1f} against {cb:.1f})"
            if apart_m > MIRROR_DISTINCT_M
            else f"returns to the same solution ({apart_m:.2f} m RMS)"
        )
        + ": the ranges choose the side"
    )
    return dataclasses.replace(best, geometry=dataclasses.replace(plain, notes=plain.notes + (note,)))
