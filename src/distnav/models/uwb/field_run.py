"""What the steps of :func:`distnav.models.uwb.field.solve_field` share (:class:`FieldRun`: the options in force, the
running totals, the starts, the robust fit of every link) and the current solution (:class:`FieldFit`), with the
steps that complete an exclusion loop that ended on an early-stopped re-fit (``field_fits.LOOP_ENDS_LOOSE``:
:func:`ends_loose`, :func:`complete`, :func:`no_worse`)."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from distnav.models.uwb import field_fits
from distnav.models.uwb.field_options import FieldOptions, subset_measurements
from distnav.models.uwb.field_steps import DISAGREE_RATIO, POLISH_BAND, REFERENCE_BAND, all_links_cost, kept_tests
from distnav.models.uwb.problems import RangingProblem
from distnav.typing import BoolArray, FloatArray

__all__ = ["FieldRun", "FieldFit", "ends_loose", "complete", "no_worse"]


@dataclass(eq=False)
class FieldRun:
    """What :func:`solve_field`'s steps share and update: the options in force (``opts``, tightened by the seed
    step) and as given, the running totals ``[iterations, messages, bytes]``, the phase marks, the starts handed to
    the next fit, the first robust fit on every link, and the note that becomes the solution's message."""

    problem: RangingProblem
    opts: FieldOptions
    given: FieldOptions
    exchange: Callable[[RangingProblem], Any] | None
    objective: str
    note: str
    fit_any: Callable[[Any], Any]  # a fit by name (make_fitter) over ``total`` and ``starts``
    loose: list[tuple[Callable[[Any], Any], float]]  # the exclusion loop's early-stopped re-fits and margins
    total: list[int]
    starts: list[FloatArray]
    marks: dict[str, tuple[int, int]] = field(default_factory=dict)  # phase -> (messages, bytes) at its end
    no_exclusion: list[Any] = field(default_factory=list)  # the first robust fit, on every link
    carry: dict[str, Any] = field(default_factory=dict)  # the common offset handed from fit to fit (solve_once)
    opening: Any = None  # the last tightening fit, tested, where it opens the exclusion loop (TIGHTEN_OPENS_LOOP)
    last_full: Any = None  # the last fit at the solver's tolerances (a loop that ends loose did not end on it)

    def fit(self, sub: Any) -> Any:
        r = self.last_full = self.fit_any(sub)
        if not self.no_exclusion:
            self.no_exclusion.append(r)
        return r

    def mark(self, phase: str) -> None:
        self.marks[phase] = (self.total[1], self.total[2])

    def cost_ratio(self, res: Any, than: Any) -> float:
        """All-links robust cost of ``res`` over that of ``than`` (:func:`all_links_cost`)."""
        return all_links_cost(self.problem, res, self.opts) / max(all_links_cost(self.problem, than, self.opts), 1e-12)

    def reference_ratio(self, res: Any) -> float:
        """:meth:`cost_ratio` of ``res`` to the robust fit of every link; where that is the loop's early-stopped
        opening (``field_fits.TIGHTEN_OPENS_LOOP``) and the ratio within :data:`REFERENCE_BAND` of
        :data:`DISAGREE_RATIO` or above, to that fit continued to the solver's tolerances (the revert's answer)."""
        ratio = self.cost_ratio(res, self.no_exclusion[0])
        if (
            self.opening is not None
            and self.no_exclusion[0] is self.opening
            and ratio > DISAGREE_RATIO / REFERENCE_BAND
        ):
            self.starts.append(np.asarray(self.opening.estimates, float))
            full = self.fit_any(self.problem)
            if full.usable and full.tests is not None and np.all(np.isfinite(full.estimates)):
                self.no_exclusion[0] = full
                ratio = self.cost_ratio(res, full)
        return ratio


@dataclass(eq=False)
class FieldFit:
    """The current solution and its link tests: ``excluded`` / ``w`` / ``flagged`` per measurement."""

    res: Any
    excluded: BoolArray
    w: FloatArray
    flagged: BoolArray
    crit: float | None
    untested: bool = False  # LM's exclusion loop got no link tests (a singular normal matrix)
    reverted: float = 0.0  # the all-links cost ratio that rejected the exclusions (0: not rejected)
    fit_scale_m: float = 0.0  # the loss scale of the final fit
    loose: bool = False  # res is an early-stopped re-fit that ended the loop (LOOP_ENDS_LOOSE): complete


def ends_loose(run: FieldRun) -> bool:
    """Whether the exclusion loop may end on a decided early-stopped re-fit (``field_fits.LOOP_ENDS_LOOSE``): where
    the polish follows it, from its solution; else (``field_fits.LOOSE_WITHOUT_POLISH``) :func:`complete` at the
    workflow's end."""
    given = run.given
    polish = given.nlos_aware and given.polish and run.opts.loss_scale_m < given.loss_scale_m
    return field_fits.LOOP_ENDS_LOOSE and bool(run.loose) and (polish or field_fits.LOOSE_WITHOUT_POLISH)


def complete(run: FieldRun, fit: FieldFit) -> FieldFit:
    """``fit`` where the loop ended on an early-stopped re-fit: that fit continued to the solver's tolerances on the
    kept links (the fit the loop would have ended with), its tests over every measurement. Where that fit fails, the
    early-stopped answer stays, said in the note, and its status is ``max_iterations``: it met the 1 cm stage's stop,
    not the solver's tolerances, so it must not read ``converged``."""
    if fit.loose:
        fit.loose = False
        run.starts.append(np.asarray(fit.res.estimates, float))
        r = run.fit(subset_measurements(run.problem, ~fit.excluded))
        if r.usable and r.tests is not None and np.all(np.isfinite(r.estimates)):
            fit.res = r
            fit.w, fit.flagged = kept_tests(run.problem.n_meas, ~fit.excluded, r.tests)
        else:  # said, not hidden: the answer stays the early-stopped fit's, whose stop was not the solver's
            run.note += (
                "; the completion of an early-stopped fit failed (unusable or untested): its 1 cm answer is kept"
            )
            if fit.res.status in ("converged", "weakly_determined"):  # met the 1 cm stage's stop, not the solver's
                fit.res = replace(fit.res, status="max_iterations", converged=False)
    return fit


def no_worse(run: FieldRun, new: FieldFit, old: FieldFit) -> bool:
    """Whether ``new`` fits all the ranges no worse than ``old`` (:func:`all_links_cost`; the per-anchor check). Where
    either ended the exclusion loop early-stopped (``field_fits.LOOP_ENDS_LOOSE``) and the costs lie within
    :data:`POLISH_BAND` of each other, those are completed first (:func:`complete`) and the fits at the solver's
    tolerances decide: a 1 cm stop moved the cost by up to 2.8e-4 of it on PLANT_HARD ``[34, 0..10]``, where the
    check's re-solve came within 6e-4 of it (``[34, 2]``, both placements)."""
    costs = [all_links_cost(run.problem, f.res, run.opts) for f in (new, old)]
    if (new.loose or old.loose) and abs(costs[0] - costs[1]) < (POLISH_BAND - 1.0) * costs[1]:
        costs = [all_links_cost(run.problem, complete(run, f).res, run.opts) for f in (new, old)]
    return costs[0] <= costs[1]
