"""Per-anchor consistency check of the link exclusions (a local, combinatorial complement of the w-tests).

An anchor with few links (4 links for 2 free coordinates under a ceiling) and one NLOS link among them is where
the global robust fit can land in the wrong basin: the anchor moves to fit the NLOS link, and a good link is
excluded in its place (the w-test then flags the wrong one — swamping). Here every anchor with an excluded or
flagged link re-decides *which* of its links to leave out, from what it holds: its own ranges and its
neighbours' current estimates. For r = 1, 2, … up to the number of links now excluded there (keeping more
links than free coordinates), it fits its own position without each r-subset of its links, with the neighbours
held — a closed-form linear trilateration start (no local minima) refined by Gauss–Newton — and stops at the
first r whose best subset fits within ``good_rms_m`` (the fewest links that explain the anchor's ranges). A
subset different from the current exclusions that fits ``improvement`` times better replaces them at that
anchor; the caller re-solves the network.
"""

from __future__ import annotations

import itertools

import numpy as np

from distnav.models.uwb.problems import RangingProblem
from distnav.typing import BoolArray, FloatArray

__all__ = ["fit_anchor", "repair_exclusions"]


def fit_anchor(problem: RangingProblem, i: int, positions_m: FloatArray, links: list[int]
               ) -> tuple[FloatArray, float]:
    """Position of anchor ``i`` from the measurements ``links`` (indices) with every other anchor held at
    ``positions_m``; returns ``(position, RMS range residual)``."""
    p = np.asarray(positions_m, float)
    other = np.where(problem.meas_a[links] == i, problem.meas_b[links], problem.meas_a[links])
    q = p[other]
    d = problem.range_m[links]
    free = problem.free[i]
    x = p[i].copy()
    # held coordinates: reduce the ranges to the free subspace
    if (~free).any():
        dz2 = np.sum((q[:, ~free] - x[~free]) ** 2, axis=1)
        dh = np.sqrt(np.maximum(d * d - dz2, 0.0))
    else:
        dh = d
    qf = q[:, free]
    # linear trilateration (differences of squared ranges against the first neighbour)
    a = 2.0 * (qf[1:] - qf[0])
    b = dh[0] ** 2 - dh[1:] ** 2 + np.sum(qf[1:] ** 2, axis=1) - np.sum(qf[0] ** 2)
    try:
        start, *_ = np.linalg.lstsq(a, b, rcond=None)
    except np.linalg.LinAlgError:
        start = x[free]
    best_x, best_rms = x[free].copy(), np.inf
    for s in (start, x[free]):
        y = np.array(s, float)
        for _ in range(20):
            diff = y - qf
            r = np.linalg.norm(diff, axis=1)
            j = diff / np.maximum(r, 1e-9)[:, None]
            step, *_ = np.linalg.lstsq(j, dh - r, rcond=None)
            y = y + step
            if np.linalg.norm(step) < 1e-9:
                break
        rms = float(np.sqrt(np.mean((np.linalg.norm(y - qf, axis=1) - dh) ** 2)))
        if rms < best_rms:
            best_x, best_rms = y, rms
    out = x.copy()
    out[free] = best_x
    return out, best_rms


def repair_exclusions(problem: RangingProblem, positions_m: FloatArray, excluded: BoolArray, flagged: BoolArray,
                      *, improvement: float = 2.0, good_rms_m: float = 0.15, max_subsets: int = 200
                      ) -> tuple[BoolArray, list[str]]:
    """New exclusions after the per-anchor check (module docstring), and one note per anchor changed."""
    ex = np.asarray(excluded, bool).copy()
    notes: list[str] = []
    k_free = problem.free.sum(axis=1)
    touched = np.zeros(problem.n_anchors, bool)
    for arr in (problem.meas_a[ex | flagged], problem.meas_b[ex | flagged]):
        touched[arr] = True
    for i in np.flatnonzero(touched & problem.estimated):
        mine = np.flatnonzero((problem.meas_a == i) | (problem.meas_b == i)).tolist()
        now_out = {m for m in mine if ex[m]}
        current = [m for m in mine if not ex[m]]
        # too few links left to check the current choice: any consistent subset is better
        rms_now = fit_anchor(problem, int(i), positions_m, current)[1] if len(current) > k_free[i] else np.inf
        chosen: tuple[float, tuple[int, ...]] | None = None
        for r in range(1, max(len(now_out), 1) + 1):  # the fewest links whose removal leaves a consistent fit
            if len(mine) - r <= k_free[i]:
                break
            best: tuple[float, tuple[int, ...]] | None = None
            for count, drop in enumerate(itertools.combinations(mine, r)):
                if count >= max_subsets:
                    break
                _, rms = fit_anchor(problem, int(i), positions_m, [m for m in mine if m not in drop])
                if best is None or rms < best[0]:
                    best = (rms, drop)
            if best is not None and best[0] <= good_rms_m:
                chosen = best
                break
        if chosen is None or set(chosen[1]) == now_out or not chosen[0] * improvement < rms_now:
            continue
        drop_set = set(chosen[1])
        ex[mine] = False
        ex[list(drop_set)] = True
        names = ", ".join(f"{problem.ids[problem.meas_a[m]]}-{problem.ids[problem.meas_b[m]]}" for m in drop_set)
        notes.append(f"anchor {problem.ids[i]!r}: its links fit best without {names} "
                     f"(RMS {chosen[0]:.3f} m vs {rms_now:.3f} m)")
    return ex, notes
