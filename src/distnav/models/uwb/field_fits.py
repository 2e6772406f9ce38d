"""The single fits of :mod:`distnav.models.uwb.field` that are not the exclusion loop's: one solve by name (LM or a
distributed solver through the exchange, its messages counted), the tightening of the one-sided loss and the
polish fit — the same steps for LM and for the distributed solvers (``FieldOptions.nlos_aware``).

The distributed path computes here only what the anchors can: every fit runs through the exchange; the robust
scatter of the residuals (:func:`scatter_m`) that sets the tightened scale is a **network total** — a median over
every link's residual, each anchor holding its own links' residuals at the solution (a deployment: one gather of
one float per link, as the result's, or a median by bisection over sum reductions); so is the cost of all the links
that decides whether the polish is kept (a sum over the anchors).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

from distnav.algorithms.ranging import csg
from distnav.algorithms.ranging.inner import FORCING_TRIED
from distnav.algorithms.ranging.qc import SCALE_FLOOR
from distnav.algorithms.ranging.stop import StopRule
from distnav.errors import ModelError
from distnav.models.uwb.problems import RangingProblem
from distnav.typing import FloatArray

__all__ = [
    "solve_once",
    "scatter_m",
    "tighten_scale",
    "TightenShared",
    "TIGHT_SCALE_FLOOR_M",
    "REFIT_TOLERANCES",
    "TIGHTEN_FITS",
    "TIGHTEN_JUMP",
    "FIRST_ITERATIONS",
    "STAGE_TOLERANCES",
    "REFIT_STAGES",
    "FORCING_STAGES",
    "STAGE_FORCING",
    "EARLY_STAGES",
    "refit_margin_w",
    "CARRY_OFFSET",
    "CARRY_HELD",
    "TIGHTEN_OPENS_LOOP",
    "TIGHTEN_MIN_FALL",
    "LOOP_ENDS_LOOSE",
    "LOOSE_WITHOUT_POLISH",
    "opens_loop",
    "opening_fit",
]

REFIT_TOLERANCES = {"ftol": 1e-10, "xtol": 1e-10}  # LM's defaults are 1e-12 (first fit)
TIGHT_SCALE_FLOOR_M = 0.05  # the one-sided loss is tightened from loss_scale_m down to this (or 3 × the scatter)
TIGHTEN_FITS = 8  # at most this many halvings
#: a distributed solver's tightening fits go straight to the target scale (max(TIGHT_SCALE_FLOOR_M, 3 × the scatter)
#: at the last solution) instead of halving towards it (issue 27, fifth session: 1.09 × fewer bytes on 12 plant-like
#: halls, positions within 0.063 mm, the same links excluded); LM keeps the halvings
TIGHTEN_JUMP = True
#: a distributed tightening jumps again only where the target fell by more than this fraction of the scale it would
#: replace (the first jump is always taken): on the hard halls the target creeps towards its fixed point by steps of
#: 0.3–2 % (``[34, 3]`` middle: 0.257, 0.252, 0.249 … 0.245 m in 7 fits), each one more fit (issue 27, ninth session,
#: docs/economy_uwb.md item 53: 100 PLANT_HARD 31.51 -> 30.40 MB, the same links and status; a 10 % band changed 4 of
#: them: the final scale decides their close calls). 0: chase while the target falls at all, as before; LM keeps the
#: halvings
TIGHTEN_MIN_FALL = 0.01
WARM_ITERATIONS = 0  # a distributed solver's warm re-fit: consensus iterations before its final distributed LM phase
#: (ftol, xtol_m) of a distributed solver's LM phase by the fit's stage in the workflow (issue 27): "seed", the fits
#: whose solution only starts the next fit (the first fit, the tightening); "refit", the exclusion loop's re-fits
#: after an exclusion, whose tests only choose the next links, and "rung", the fit that continues one whose choice
#: its margin left open (:data:`REFIT_STAGES`). The loop's first fit, its last (one full fit from the last re-fit:
#: :func:`~distnav.algorithms.ranging.qc.exclude_links`) and the polish keep the solver's StopRule (1e-6, 0.1 mm): any
#: of them can be the answer, and on plant corner #0 a loop whose every re-fit stopped at 0.3–1 mm steps ended 1.5 mm
#: from LM's answer where the full tolerance ends 0.3 mm from it.
STAGE_TOLERANCES = {"seed": (1e-3, 1e-2), "refit": (1e-3, 1e-2), "rung": (3e-4, 3e-3)}
#: the exclusion loop's early-stopped re-fits, loosest first, each deciding with :func:`refit_margin_w` (issue 27;
#: () every re-fit at the solver's tolerances, as before). A choice the 1 cm re-fit leaves open goes to a 3 mm fit
#: (margin 0.24) before the full one; a decided end of the loop goes straight to the full fit
#: (:func:`~distnav.algorithms.ranging.qc.exclude_links`). Sixth session: 1.03 × fewer bytes on 12 plant-like halls
#: (corner #0 1.32 ×, middle #0 0.94 ×, the other 10 the same bytes; 10⁴ anchors, with items 20–21: 0.45 % more),
#: the same links excluded. The fourth session's ladder (1 cm, 1 mm) climbed every rung at the loop's end too:
#: 1.04 × where one rung gave 1.08 ×
REFIT_STAGES: tuple[str, ...] = ("refit", "rung")
#: the adaptive forcing term of a distributed fit's LM phase (``RunOptions.refine_forcing``: ``(γ, α, η₀, η_min,
#: η_max[, stop_η])``, :class:`~distnav.algorithms.ranging.inner.Forcing`) in the stages :data:`FORCING_STAGES`
#: only: the exclusion loop's early-stopped re-fits and rungs, whose answers only choose links with a margin
#: (:func:`refit_margin_w`) — never the first fit or the tightening ("seed"), whose answers move the next fits (issue
#: 27, docs/economy_uwb.md items 33 and 36: the term in one fit of the folded plant corner #0, its fifth, a
#: tightening fit, excluded a link LM keeps). :data:`~distnav.algorithms.ranging.inner.FORCING_TRIED` with a stop
#: allowed on any step (stop_η = η_max 0.9): 12 plant-like halls 2.698 → 2.388 MB, the same links and status, within
#: 0.10 mm; 100 PLANT_HARD halls and APRIL datasets 4–5 the same links, status and exit codes, within 1 mm. None:
#: every fit to ``CG_RTOL``, as before. The one switch of the forcing term in the workflow: item 33's experiment
#: (the term in every early-stopped fit, a stop only on a step solved to ``inner.STOP_ETA``) is
#: ``STAGE_FORCING = FORCING_TRIED`` with ``FORCING_STAGES = EARLY_STAGES``
STAGE_FORCING: tuple[float, ...] | None = (*FORCING_TRIED, 0.9)
FORCING_STAGES: tuple[str, ...] = ("refit", "rung")
#: every stage whose fits stop early (:data:`STAGE_TOLERANCES`: at 3 mm or 1 cm steps), whose answers are replaced
EARLY_STAGES: tuple[str, ...] = ("seed", "refit", "rung")
#: a warm distributed fit starts from the last fit's common range offset (every anchor holds it; :func:`solve_once`)
#: instead of 0 (issue 27: from 0 each re-fit's first rounds found the offset again, 0.3 m on the plant-like halls)
CARRY_OFFSET = True
#: a warm distributed fit's LM phase starts from the last fit's final Marquardt damping (floored at MU_FLOOR) instead of
#: refine.MU0 (issue 27)
CARRY_DAMPING = True
MU_FLOOR = 1e-6
#: a warm distributed fit's LM phase sends no first parameters from an anchor whose ranged neighbours hold its start
#: bit for bit from the last fit (:func:`_held`, ``RunOptions.refine_held_m``; issue 27 sixth session, item 23)
CARRY_HELD = True
#: a distributed solver's last tightening fit (all the links, at the tight scale, stopped at the seed's 1 cm) is
#: tested and opens the exclusion loop as its first early-stopped re-fit (``qc.exclude_links(opening=…)``), its choice
#: taken where decided with the re-fit's margin, instead of a full fit of every link from its solution (issue 27,
#: seventh session; the robust fit of every link, the revert's reference, is completed only where a ratio needs it)
TIGHTEN_OPENS_LOOP = True
#: the exclusion loop may end on a decided early-stopped re-fit where the polish follows: the full fit of the kept
#: links runs only where the polish is not kept or a cost ratio comes near its threshold (``field_run.complete``; issue
#: 27, seventh session) — the polish, from the early-stopped solution, is then the answer
LOOP_ENDS_LOOSE = True
#: with :data:`LOOP_ENDS_LOOSE`, the loop ends on its decided early-stopped re-fit also where no polish follows (no
#: tightened scale, or ``polish=False``): the workflow's last step completes that end (``field_run.complete``: the
#: fit at the solver's tolerances of the kept links from it, the fit the loop ended on before), and until then the
#: per-anchor check and the revert use the early-stopped end as they do where the polish follows — the check's
#: re-solve then also ends early-stopped and is completed only where its cost comes near the first choice's
#: (``field_run.no_worse``). False: without the polish the loop ends on the full fit, as before (issue 27, ninth
#: session, docs/economy_uwb.md item 52: 100 PLANT_HARD 32.11 -> 31.51 MB, the same links and status, within 0.2 mm)
LOOSE_WITHOUT_POLISH = True
FIRST_ITERATIONS = 0  # its first fit (from the prepared start): the same, issue 27 (solve_once's docstring)


def solve_once(
    problem: RangingProblem,
    solver: str,
    kw: dict[str, Any],
    iterations: int,
    *,
    exchange: Callable[[RangingProblem], Any] | None = None,
    total: list[int] | None = None,
    start: str = "cold",
    tolerances: bool = True,
    stage: str | None = None,
    carry: dict[str, Any] | None = None,
) -> Any:
    """One solve of ``problem`` (its ``initial_m`` the start) by ``solver`` with the keyword arguments ``kw``.
    ``start="warm"``: a re-fit from a solution, the robust loss straight away (no graduated linear phase; LM with
    :data:`REFIT_TOLERANCES` unless ``kw`` sets them or ``tolerances`` is False). A distributed solver runs on
    ``exchange(problem)``; its warm re-fit runs :data:`WARM_ITERATIONS` consensus iterations, then the final
    distributed LM phase (:mod:`distnav.algorithms.ranging.refine`) from the solution — unless that phase is off
    (``kw["refine"]`` False: all ``iterations``). Why: from a solution the consensus iterations first move away
    from it (N-CLM's fixed point is not LM's: warm at LM's solution of a plant-like corner hall, its iterate was
    1.48 m RMS off after 500 iterations), and at a tightened loss scale the LM phase can then end in another
    basin (plant corner #0 of ``reproduce uwb-field``: 0.449 m against LM's 0.354 m on the same links); with 0
    the phase stays in the solution's basin, as LM's warm re-fit, for 5 % of the messages. ``start="first"``: the first
    fit of the workflow (from the prepared start) runs :data:`FIRST_ITERATIONS` consensus iterations before that
    phase (issue 27): the 500 iterations cost 55 % of the bytes of a whole ``uwb solve`` on plant-like halls
    (33 of 59 MB on ``[78, 0]``) and the workflow ended at the same positions without them (within 1 µm on 12
    plant-like halls, docs/economy_uwb.md). ``total`` (iterations, messages, bytes) is incremented by the
    solve's: its iterations plus its distributed LM phase's rounds, its broadcasts and its LM phase's network
    totals as spanning-tree reductions (``settings["refine"]``,
    :func:`~distnav.algorithms.ranging.wire.reduction_cost`). ``stage`` (``"seed"``; None: the solver's
    own): a distributed solver's LM phase stops at :data:`STAGE_TOLERANCES` — a fit whose solution only
    starts the next one needs no 0.1 mm steps (issue 27, docs/economy_uwb.md); in :data:`FORCING_STAGES` its CG
    runs with the forcing term :data:`STAGE_FORCING` (where set). ``carry``: the common range offset
    handed from fit to fit (:data:`CARRY_OFFSET`): a warm distributed re-fit starts from the last fit's, which every
    anchor holds (no message), instead of 0; the fit's own is stored for the next — with its LM phase's final
    coordinates and links, which every ranged neighbour holds (:data:`CARRY_HELD`: a warm fit sends no first
    parameters from an anchor that starts there)."""
    key = solver.upper()
    warm, first = start == "warm", start == "first"
    extra: dict[str, Any] = {}
    if key != "LM" and exchange is not None:
        extra["exchange"] = exchange(problem)
    if warm and "graduated" not in kw and "objective" in kw:
        extra["graduated"] = False if key == "LM" else 0
    if warm and tolerances and key == "LM":
        extra.update({k: v for k, v in REFIT_TOLERANCES.items() if k not in kw})
    if warm and key != "LM" and kw.get("refine", True) is not False:
        iterations = min(iterations, WARM_ITERATIONS)
    elif first and key != "LM" and kw.get("refine", True) is not False:
        iterations = min(iterations, FIRST_ITERATIONS)
    if stage is not None and key != "LM" and "stop" not in kw:
        ftol, xtol_m = STAGE_TOLERANCES[stage]
        extra["stop"] = StopRule(refine_ftol=ftol, refine_xtol_m=xtol_m)
        if STAGE_FORCING is not None and stage in FORCING_STAGES and "refine_forcing" not in kw:
            extra["refine_forcing"] = tuple(STAGE_FORCING)  # the loop's re-fits only (STAGE_FORCING)
    if carry is not None and warm and key != "LM":
        extra.update({k: v for k, v in carry.items() if k not in kw and _carries(k, key, kw)})
        if CARRY_HELD and "held" in carry and iterations == 0 and kw.get("refine", True) is not False:
            extra["refine_held_m"] = _held(problem, carry["held"])  # the LM phase starts at the fit's start
    r = csg.solve(problem, key, iterations=iterations, **kw, **extra)
    if carry is not None and key != "LM" and r.usable:
        _carry(r, carry, problem)
    if total is not None:  # the final distributed LM phase's rounds are iterations too (issue 28 item 3)
        ref = (getattr(r, "settings", None) or {}).get("refine") or {}
        total[0] += int(r.iterations) + int(ref.get("rounds", 0))
        total[1] += int(r.comm.messages) + int(ref.get("reduction_messages", 0))
        total[2] += int(r.comm.bytes) + int(ref.get("reduction_bytes", 0))
    return r


def scatter_m(problem: RangingProblem, positions_m: FloatArray) -> float:
    """Robust scatter of the range residuals at ``positions_m``: 1.4826 × their median absolute deviation about
    the median (a common range offset moves the median, not the scatter; NLOS links, a minority, barely move it).
    A network total (module docstring)."""
    e = problem.residuals_m(positions_m)
    return float(1.4826 * np.median(np.abs(e - np.median(e)))) if e.size else 0.0


@dataclass(frozen=True, kw_only=True, eq=False)
class TightenShared:
    """What :func:`tighten_scale`'s fits share with the rest of a workflow (one settings piece; each default: not
    used): ``exchange`` (a distributed solver's, per problem), ``total`` (the running iterations, messages, bytes),
    ``stage`` and ``carry`` (:func:`solve_once`'s) and ``results`` (each fit's result appended; the fits then run
    with their link tests)."""

    exchange: Callable[[RangingProblem], Any] | None = None
    total: list[int] | None = None
    stage: str | None = None
    carry: dict[str, Any] | None = None
    results: list[Any] | None = None

    def __post_init__(self) -> None:
        if self.stage is not None and self.stage not in STAGE_TOLERANCES:
            raise ModelError(
                f"TightenShared.stage must be one of {', '.join(STAGE_TOLERANCES)} or None, got {self.stage!r}"
            )


def tighten_scale(
    problem: RangingProblem,
    start_m: FloatArray,
    solver: str,
    kw: dict[str, Any],
    scale_m: float,
    iterations: int,
    shared: TightenShared | None = None,
) -> tuple[FloatArray, float, int]:
    """The one-sided fit of every link by ``solver``, its loss scale halved from ``scale_m`` (each fit warm from the
    last solution) down to :data:`TIGHT_SCALE_FLOOR_M` or 3 × :func:`scatter_m`, whichever is larger (``shared``:
    :class:`TightenShared`); a distributed solver with :data:`TIGHTEN_JUMP` goes to that target at
    once, the target recomputed at each fit's solution (the loop ends where it no longer falls, or after the first
    jump by no more than :data:`TIGHTEN_MIN_FALL`). Returns
    ``(positions, final scale, fits)`` (see :func:`distnav.models.uwb.field.tighten`). ``shared.results``: each fit's
    result is appended to it, and the fits run with their link tests (``quality``; :data:`TIGHTEN_OPENS_LOOP`: the
    last one, at the final scale, opens the exclusion loop).

    Why the jump (issue 27): each halving is one more distributed fit (its start and its rounds; 166 kB of 937 on
    the plant-like hall ``[78, 0]``); the halvings only lead the solution through the intermediate scales, and on
    12 plant-like halls the jump ended within 0.063 mm of them, the same links excluded, the tight scale within
    2.1 % (docs/economy_uwb.md, fifth session). Not for LM, whose fits send nothing."""
    sh = shared or TightenShared()
    results = sh.results
    kw = {**kw, "quality": results is not None}
    pos = np.asarray(start_m, float)
    scale, fits = float(scale_m), 0
    jump = TIGHTEN_JUMP and solver.upper() != "LM"
    while fits < TIGHTEN_FITS:
        target = max(TIGHT_SCALE_FLOOR_M, 3.0 * scatter_m(problem, pos))
        if scale <= target * (1 + 1e-9) or (jump and fits and target > scale * (1.0 - TIGHTEN_MIN_FALL)):
            break
        scale = target if jump else max(scale / 2.0, target)
        kw["loss_scale_m"] = scale
        r = solve_once(
            problem.with_initial(pos),
            solver,
            kw,
            iterations,
            exchange=sh.exchange,
            total=sh.total,
            start="warm",
            tolerances=False,
            stage=sh.stage,
            carry=sh.carry,
        )
        fits += 1
        if results is not None:
            results.append(r)
        if not (r.usable and np.all(np.isfinite(r.estimates))):
            break
        pos = np.asarray(r.estimates, float)
    return pos, scale, fits


def opens_loop(solver: str, exclude: bool, staged: bool) -> bool:
    """Whether a distributed solver's last tightening fit opens the exclusion loop (:data:`TIGHTEN_OPENS_LOOP`):
    with exclusions and staged tolerances, the seed's stop no looser than the loop's first early-stopped re-fit's,
    whose margin (:func:`refit_margin_w`) then decides its choice."""
    if not (TIGHTEN_OPENS_LOOP and exclude and staged and REFIT_STAGES) or solver.upper() == "LM":
        return False
    seed, rung = STAGE_TOLERANCES["seed"], STAGE_TOLERANCES[REFIT_STAGES[0]]
    return seed[0] <= rung[0] and seed[1] <= rung[1]


def opening_fit(results: list[Any] | None) -> Any:
    """The last tightening fit (:func:`tighten_scale`'s ``results``; run at the final scale) where it can open the
    exclusion loop: usable and tested; None otherwise."""
    r = results[-1] if results else None
    if r is None or not (r.usable and r.tests is not None and np.all(np.isfinite(r.estimates))):
        return None
    return r


def refit_margin_w(stage: str, sigma_m: float) -> float:
    """The margin in |w| within which a re-fit stopped at ``stage`` (:data:`STAGE_TOLERANCES`) leaves the exclusion
    loop's choice undecided: both ends of a link off by the stage's step tolerance change its residual by up to
    ``2 · xtol_m``, its whitened residual by that over ``sigma_m`` and its w by that over the smallest robust
    scale of the tests (:data:`~distnav.algorithms.ranging.qc.SCALE_FLOOR`)."""
    return 2.0 * STAGE_TOLERANCES[stage][1] / (sigma_m * SCALE_FLOOR)


def _carries(name: str, key: str, kw: dict[str, Any]) -> bool:
    """Whether a warm fit of ``key`` with ``kw`` takes the carried setting ``name`` (:func:`_carry`)."""
    if name == "held":
        return False  # not a setting: read by :func:`_held`
    if name == "initial_offset_m":
        return CARRY_OFFSET and key != "CSG" and kw.get("range_offsets") == "common"
    return CARRY_DAMPING and kw.get("refine", True) is not False


def _carry(r: Any, carry: dict[str, Any], problem: RangingProblem) -> None:
    """What a distributed fit hands to the next warm one: its common offset and its LM phase's final damping —
    values every anchor that took part in its LM phase holds at the end (no message). The anchors without a free
    parameter may have sat that phase out (``refine.SIT_OUT``) and hold neither: a warm fit where they take part
    (the plan does not apply) sends them both first (``inner.hand_over``, 16 B each, counted)."""
    off = getattr(r, "offsets_m", None)
    if off is not None and np.size(off) == 1:
        carry["initial_offset_m"] = float(np.ravel(off)[0])
    ref = (getattr(r, "settings", None) or {}).get("refine") or {}
    mu = ref.get("mu")
    if mu is not None:
        carry["refine_mu0"] = max(float(mu), MU_FLOOR)
    carry.pop("held", None)
    if ref and np.all(np.isfinite(r.estimates)):  # its LM phase's last accepted coordinates (every neighbour's)
        carry["held"] = (problem.ids, np.array(r.estimates, float), _link_keys(problem))


def _link_keys(problem: Any) -> np.ndarray:
    """Every ranged pair of ``problem``, both ways, as sorted keys ``a · n + b``."""
    a, b, n = np.asarray(problem.meas_a), np.asarray(problem.meas_b), problem.n_anchors
    return np.unique(np.r_[a * n + b, b * n + a])


def _held(problem: RangingProblem, held: tuple[Any, np.ndarray, np.ndarray]) -> np.ndarray:
    """``RunOptions.refine_held_m`` of a warm fit of ``problem`` (:data:`CARRY_HELD`): per anchor, the last fit's
    coordinates where its start is bit for bit those on every free coordinate and every one of its links was a
    link of the last fit (so that each of its receivers holds them), NaN elsewhere — a revert's start, a link
    back. Every anchor can tell: the starts and the links are the workflow's, which every anchor follows."""
    ids, last_m, keys = held
    out = np.full((problem.n_anchors, problem.dim), np.nan)
    if tuple(ids) != tuple(problem.ids) or problem.initial_m is None or last_m.shape != out.shape:
        return out
    start = np.asarray(problem.initial_m, float)
    same = np.all((start == last_m) | ~problem.free, axis=1)
    now = _link_keys(problem)
    new = now[~np.isin(now, keys)]  # a pair not ranged in the last fit: neither end holds the other's row
    same[new // problem.n_anchors] = False
    same[new % problem.n_anchors] = False
    out[same] = last_m[same]
    return out
