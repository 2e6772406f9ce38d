"""Checks of ``distnav uwb solve`` and ``uwb import-april`` input before any solving: option values, the
anchors of the position files against the range log, the number of known anchors a frame needs, the initial
guess (no two anchors at one point: the range derivatives there are undefined) and ``--known`` of the APRIL
import (whole numbers, no id twice, at least two). Each raises :class:`~distnav.errors.DataFileError` (naming the
file and line) or :class:`~distnav.errors.ModelError`: exit code 2 at the CLI."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from distnav.algorithms.ranging.objective import DELAY_MODES
from distnav.errors import DataFileError, ModelError
from distnav.formats.uwb.io import MAX_PLAUSIBLE_RANGE_M, read_heights, read_positions, same_number_ids
from distnav.models.uwb.field import FieldOptions
from distnav.models.uwb.problems import RangingProblem

__all__ = ["april_known_ids", "check_gauge", "check_initial_distinct", "every_anchor", "held_heights"]
__all__ += ["check_applicable", "check_known_spelling", "validate_options"]

#: two anchors of an initial guess closer than this (m) are at one point
COINCIDENT_M = 1e-6


def validate_options(opts: FieldOptions) -> None:
    """The option values of ``uwb solve`` that the parser cannot judge alone (ModelError naming the option)."""
    if opts.loss != "linear" and opts.solver.upper() == "CSG":
        raise ModelError(
            f"--loss {opts.loss} is implemented for LM and the neighbourhood solvers, not CSG (pass --loss linear)"
        )
    if opts.iterations < 1:
        raise ModelError(f"--iterations must be ≥ 1, got {opts.iterations}")
    for name, v in (
        ("--sigma-m", opts.sigma_m),
        ("--loss-scale-m", opts.loss_scale_m),
        ("--offset-prior-sigma-m", opts.offset_prior_sigma_m),
    ):
        if not (np.isfinite(v) and v > 0):
            raise ModelError(f"{name} must be a positive number of metres, got {v}")
    if not (np.isfinite(opts.delay_sigma_m) and opts.delay_sigma_m >= 0):
        raise ModelError(f"--delay-sigma-m must be a number of metres ≥ 0, got {opts.delay_sigma_m}")
    for name, v in (("--sigma-m", opts.sigma_m), ("--delay-sigma-m", opts.delay_sigma_m)):
        if v > MAX_PLAUSIBLE_RANGE_M:  # 1e308 overflowed (a traceback) or said "no accuracy can be stated"
            raise ModelError(
                f"{name} {v:g} m: a range σ over {MAX_PLAUSIBLE_RANGE_M:g} m, the longest range UWB measures, "
                "states nothing (was it in mm or cm?)"
            )
    if not (np.isfinite(opts.reliability_limit_m) and opts.reliability_limit_m >= 0):
        raise ModelError(f"--reliability-limit-m must be a number of metres ≥ 0, got {opts.reliability_limit_m}")
    if not 0.0 < opts.level < 0.5:
        raise ModelError(f"--level must lie in (0, 0.5), got {opts.level}")
    if opts.range_offsets not in ("none", "auto") and opts.objective != "metres":
        raise ModelError(f"--range-offsets {opts.range_offsets} is estimated with --objective metres only")
    if opts.range_offsets == "common_delays" and opts.solver.upper() != "LM":
        raise ModelError(f"--range-offsets common_delays is LM's only (--solver {opts.solver}: common or per_anchor)")


def check_applicable(opts: FieldOptions) -> None:
    """Refuse a σ option given (not its default) where the solve does not use it: it was silently ignored
    (guard13's sweep). ``--offset-prior-sigma-m`` is the prior of estimated per-anchor delays (``--range-offsets
    per_anchor`` or ``common_delays``); ``--delay-sigma-m`` the delays admitted in σ when they are not estimated,
    with the metres objective (:attr:`FieldOptions.considers_delays`)."""
    default = FieldOptions()
    estimated = opts.range_offsets in DELAY_MODES
    if opts.offset_prior_sigma_m != default.offset_prior_sigma_m and not estimated:
        raise ModelError(
            f"--offset-prior-sigma-m {opts.offset_prior_sigma_m:g} is the prior σ of estimated per-anchor delays: "
            f"it applies with --range-offsets per_anchor or common_delays, not {opts.range_offsets}"
        )
    if opts.delay_sigma_m != default.delay_sigma_m and (estimated or opts.objective != "metres"):
        raise ModelError(
            f"--delay-sigma-m {opts.delay_sigma_m:g} admits delays that are not estimated, with --objective metres: "
            f"it does not apply with --objective {opts.objective} and --range-offsets {opts.range_offsets}"
        )


def held_heights(
    heights: Path | None,
    known: Path,
    ranges: Path,
    *,
    dim: int,
    ids: dict[str, int],
    known_pos: dict[str, Any],
) -> dict[str, dict[int, float]]:
    """``{anchor: {2: z}}`` of the estimated anchors whose heights ``heights`` holds (DataFileError naming the file
    and line of an anchor the log does not have, or heights for a 2-D network)."""
    held: dict[str, dict[int, float]] = {}
    if heights is None:
        return held
    if dim != 3:
        raise DataFileError(f"{heights}: heights need a 3-D network, but {known} has no z_m column")
    hz, hline = read_heights(heights)
    for k, z in hz.items():
        if k not in ids:
            raise DataFileError(f"{heights}:{hline[k]}: anchor {k!r} does not appear in {ranges}")
        if k not in known_pos:  # a known anchor's line is ignored: its surveyed position holds (hall files list all)
            held[k] = {2: z}
    return held


def every_anchor(path: Path, what: str, ids: Sequence[str], dim: int, known: Path) -> np.ndarray:
    """The positions of ``path`` for every anchor of the log, in its order (DataFileError: another dimension than
    ``known``'s, or an anchor missing)."""
    pos, d = read_positions(path)
    if d != dim:
        raise DataFileError(f"{path}: has {d}-D positions but {known} has {dim}-D")
    missing = [k for k in ids if k not in pos]
    if missing:
        raise DataFileError(f"{path}: {what} lacks anchor(s) {', '.join(repr(m) for m in missing[:10])}")
    return np.array([pos[k] for k in ids])


def check_gauge(problem: RangingProblem) -> None:
    """The number of known anchors a frame needs (what build_problem checks first; ModelError otherwise)."""
    fixed = problem.fixed
    planar = problem.dim == 2 or bool(np.all(~problem.free[~fixed, 2]))
    need = 2 if planar else 3
    if int(fixed.sum()) < need:
        what = (
            "2 fixed anchors (2-D, or 3-D with every height held)" if planar else "3 non-collinear fixed anchors in 3-D"
        )
        raise ModelError(f"the problem is not determined: it needs at least {what}, got {int(fixed.sum())}")


def check_initial_distinct(path: Path, ids: Sequence[str], initial_m: np.ndarray, known_m: Mapping[str, Any]) -> None:
    """Refuse an initial guess that puts two anchors at one point (the known ones at their known positions): the
    derivative of a range between them is undefined (0/0) and the solvers cannot start there."""
    pos = np.array(
        [np.asarray(known_m[k], float) if k in known_m else initial_m[i] for i, k in enumerate(ids)], dtype=float
    )
    _, inverse, counts = np.unique(np.round(pos / COINCIDENT_M), axis=0, return_inverse=True, return_counts=True)
    shared = np.flatnonzero(counts[inverse.ravel()] > 1)
    if shared.size:
        a = int(shared[0])
        b = int(next(j for j in shared[1:] if inverse.ravel()[j] == inverse.ravel()[a]))
        where = ", ".join(f"{v:g}" for v in pos[a])
        raise DataFileError(
            f"{path}: anchors {ids[a]!r} and {ids[b]!r} have the same initial position ({where}) m"
            f"{f' ({shared.size} anchors share positions)' if shared.size > 2 else ''}: an initial guess needs every "
            f"anchor at its own point (or leave out --initial for the MDS guess)"
        )


def april_known_ids(text: str, choices: Sequence[int]) -> list[int]:
    """``--known`` of ``uwb import-april``: comma-separated node ids, each one of ``choices`` (the nodes with
    ground truth), none twice, at least two (a 2-D frame needs two fixed anchors)."""
    parts = [k.strip() for k in str(text).split(",")]
    if any(not k.lstrip("+").isdigit() for k in parts if k) or not any(parts):
        raise DataFileError(f"--known must be comma-separated node ids (e.g. 8,12,54,87), got {text!r}")
    known = [int(k) for k in parts if k]
    for k in known:
        if k not in choices:
            raise DataFileError(f"--known: node {k} has no ground truth; choose from {sorted(choices)}")
    twice = sorted({k for k in known if known.count(k) > 1})
    if twice:
        raise DataFileError(f"--known names node(s) {', '.join(map(str, twice))} twice, got {text!r}")
    if len(known) < 2:
        raise DataFileError(
            f"--known {text!r}: a 2-D frame needs at least 2 known nodes (their positions fix it), got {len(known)}"
        )
    return known


def check_known_spelling(known: Path, ranges: Path, unused_known: Sequence[str], ids: Sequence[str]) -> None:
    """A known anchor without ranges whose id the log spells as another number (``8`` in ``known``, ``08`` in the
    log): the same anchor, which would be estimated as an unknown one while its known position is ignored (before:
    a warning "known anchors without ranges are ignored" and a worse map)."""
    for k in unused_known:
        twins = same_number_ids(k, ids)
        if twins:
            raise DataFileError(
                f"{known}: known anchor {k!r} has no range in {ranges}, which has {twins[0]!r}: the same anchor "
                f"spelled two ways? (spell its id alike in both files)"
            )
