"""The cut test: a part of the network placed by fewer checks than the exclusions took from it is reported weak.

The link tests see an NLOS link when its bias shows in its own residual. A connected group of anchors can move
*together* instead (stress bench, NLOS 20 %: a group of 5–7 anchors shifted 1.0–1.5 m, every kept link fitting to
0.11 m or better): its inner links move with it and say nothing about where it sits; only the links across the cut
between the group and the rest place it. Placing a rigid part takes ``dof`` of them (3 in the horizontal plane:
two translations and a rotation; 6 when heights are free), so the cut's redundancy — the checks of that placement
— is ``k − dof`` with ``k`` kept cut links. When the exclusions took **more** links off that cut than it has
redundancy left (``e > k − dof``), the excluded links together with ``dof`` kept ones outnumber the kept set: which
side of the cut is NLOS was not decided by a majority, and a placement resting on the excluded links would have
as much support as the reported one. The part is then reported weak (reason ``cut``), its positions unchanged.
This is a breakdown-point argument (a robust fit tolerates fewer outliers than it has redundancy), not a fitted
threshold; docs/uwb.md ("External reliability") gives the numbers on the bench and on held-out seeds.

The parts tested are grown greedily from every estimated anchor with an excluded link: the neighbour (by any link,
estimated anchors only) that most raises the ratio ``e / k`` of the cut joins while the ratio rises. Parts of one
anchor are left to the per-anchor rules (``thin``, ``reliability``: an anchor's own redundancy is what they test);
a part never holds a known anchor (it would not be a free rigid body): the growth admits estimated anchors
only. Above :data:`MAX_ANCHORS` anchors the test
is skipped (the greedy growth is quadratic in a part's neighbours). Every anchor can compute its links' exclusion
flags; the growth itself is a computation on the link graph with one bit per link (a network total, as the
all-links cost of :mod:`distnav.models.uwb.field`), not a node-local test.
"""

from __future__ import annotations

import numpy as np

from distnav.models.uwb.problems import RangingProblem
from distnav.typing import BoolArray

__all__ = ["MAX_ANCHORS", "cut_parts", "cut_weak"]

MAX_ANCHORS = 200


def _rigid_dof(problem: RangingProblem, part: BoolArray) -> int:
    """Degrees of freedom of a rigid motion of ``part``: 3 (plane), 6 when a height in it is free (3-D)."""
    return 6 if problem.dim == 3 and bool(problem.free[part, 2].any()) else 3


def cut_parts(problem: RangingProblem, excluded: BoolArray) -> list[tuple[BoolArray, int, int]]:
    """The distinct parts grown from each estimated anchor with an excluded link (module docstring), each with
    ``(part mask, e excluded cut links, k kept cut links)``; singletons included (the caller chooses)."""
    ex = np.asarray(excluded, bool)
    n = problem.n_anchors
    a, b = problem.meas_a, problem.meas_b
    est = problem.estimated
    # per anchor: its links as (other end, excluded)
    nbr: list[list[tuple[int, bool]]] = [[] for _ in range(n)]
    for u, v, x in zip(a.tolist(), b.tolist(), ex.tolist(), strict=True):
        nbr[u].append((v, x))
        nbr[v].append((u, x))
    touched = np.zeros(n, bool)
    touched[a[ex]] = True
    touched[b[ex]] = True
    out: list[tuple[BoolArray, int, int]] = []
    seen: set[bytes] = set()
    for i in np.flatnonzero(touched & est).tolist():
        part = np.zeros(n, bool)
        part[i] = True
        e = sum(x for _, x in nbr[i])
        k = len(nbr[i]) - e
        while True:
            best: tuple[float, int, int, int] | None = None
            cand = {j for u in np.flatnonzero(part).tolist() for j, _ in nbr[u] if not part[j] and est[j]}
            for j in sorted(cand):
                de = dk = 0  # j joins: its links into the part leave the cut, its links out of it join the cut
                for o, x in nbr[j]:
                    s = -1 if part[o] else 1
                    de, dk = (de + s, dk) if x else (de, dk + s)
                e2, k2 = e + de, k + dk
                ratio = e2 / max(k2, 1)
                if ratio > e / max(k, 1) + 1e-12 and (best is None or ratio > best[0]):
                    best = (ratio, j, e2, k2)
            if best is None:
                break
            _, j, e, k = best
            part[j] = True
        key = np.packbits(part).tobytes()
        if key not in seen:
            seen.add(key)
            out.append((part, e, k))
    return out


def cut_weak(problem: RangingProblem, excluded: BoolArray) -> dict[str, str]:
    """The anchors of every part of two or more estimated anchors whose excluded cut links exceed the cut's
    redundancy (``e > k − dof``; module docstring), each with its reason. Empty above :data:`MAX_ANCHORS`."""
    if problem.n_anchors > MAX_ANCHORS:
        return {}
    out: dict[str, str] = {}
    for part, e, k in cut_parts(problem, excluded):
        if part.sum() < 2:  # parts grow over estimated anchors only
            continue
        dof = _rigid_dof(problem, part)
        if e <= k - dof:
            continue
        names = [problem.ids[i] for i in np.flatnonzero(part)]
        listed = " ".join(names[:8]) + (" ..." if len(names) > 8 else "")
        reason = (
            f"cut: its part of {len(names)} anchors ({listed}) is placed by {k} kept links to the rest and "
            f"{e} of its links to the rest were excluded: more than the {max(k - dof, 0)} redundant ones left "
            f"({k} - {dof} for its rigid placement); the excluded links could place it as well"
        )
        for nm in names:
            out.setdefault(nm, reason)
    return out
