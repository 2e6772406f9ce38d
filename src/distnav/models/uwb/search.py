"""The handedness of the distributed solvers' start (issue 28's open defect).

LM's workflow fits every link from several starts and keeps the lowest robust cost
(:func:`~distnav.models.uwb.field.choose_start`); the distributed solvers start from the prepared MDS/SMACOF map
alone. Known anchors clustered in a corner fix that map's handedness only through the few metres they span, and
the MDS map's own distortion can make the reflected alignment fit them better: on plant-like hall seed 30 of
``bench_uwb_verdict.py`` every solver ended at the mirror image (22 m RMSE, kept ranges fitted to 1.9 cm, two
anchors "meeting" 0.3 m while 6–10 m off).

:func:`choose_handedness` decides between the prepared start and the same map aligned with the other handedness
(:func:`~distnav.models.uwb.initial.candidate_starts`' ``handedness`` start) by one centralized robust LM fit of
every link from each (LM's multi-start restricted to those two starts, compared by the same cost), and hands the
distributed solver the *start* whose fit was lower — not the LM solution, so the distributed solve itself is
unchanged wherever the prepared start wins. Centralized like the MDS start it chooses between (a classical MDS
needs every range at one place); no message of the distributed solve is added, and its iterations are not counted
as the solve's (``summary.json`` ``iterations`` stays the distributed solver's).
"""

from __future__ import annotations

import dataclasses

import numpy as np

from distnav.algorithms.ranging.lm import solve_lm
from distnav.models.uwb.field import MULTI_START_MAX_ANCHORS, START_TOLERANCES, FieldOptions, solver_kwargs
from distnav.models.uwb.initial import candidate_starts
from distnav.models.uwb.problems import RangingProblem

__all__ = ["choose_handedness"]


def choose_handedness(problem: RangingProblem, opts: FieldOptions) -> tuple[RangingProblem, str]:
    """``(problem, note)``: the problem with the ``handedness`` start as its initial guess when its robust LM fit
    of every link has the lower objective (the note says so), else ``problem`` unchanged and an empty note. Only for
    a distributed solver with the metres objective and ``multi_start`` (LM has the full multi-start) and networks
    up to :data:`~distnav.models.uwb.field.MULTI_START_MAX_ANCHORS` anchors."""
    if (
        opts.solver.upper() == "LM"
        or not opts.multi_start
        or opts.objective != "metres"
        or problem.initial_m is None
        or problem.n_anchors > MULTI_START_MAX_ANCHORS
    ):
        return problem, ""
    other = dict(candidate_starts(problem)).get("handedness")
    if other is None:
        return problem, ""
    lm = dataclasses.replace(opts, solver="LM", solver_options={})
    kw = {**solver_kwargs(lm), "quality": False, **START_TOLERANCES}
    cost = []
    for start in (problem.initial_m, other):
        r = solve_lm(problem.with_initial(start), max_iterations=opts.iterations, **kw)  # not the workflow's solver
        ok = r.usable and np.all(np.isfinite(r.estimates))
        cost.append(float(r.objective) if ok else np.inf)
    if not cost[1] < cost[0]:
        return problem, ""
    note = (
        f"; start: the MDS map aligned with the other handedness (its robust LM fit of every link {cost[1]:.4g} "
        f"against the prepared start's {cost[0]:.4g})"
    )
    return problem.with_initial(other), note
