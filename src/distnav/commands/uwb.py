"""``distnav uwb solve``: anchor positions from a real (or simulated) inter-anchor range log.

    distnav uwb solve --ranges RANGES.csv --known KNOWN.csv [--initial INIT.csv] [--solver NAME]
                      [--truth TRUTH.csv] [--heights HEIGHTS.csv] [--loss linear|huber|cauchy]
                      [--loss-scale-m 0.3] [--required-accuracy-m 0.3] [--iterations 500]
                      [--backend inprocess|mpi] --out OUT_DIR

* Repeated ranges of a pair are combined by their **median** (robust to a minority of NLOS ranges).
* Without ``--initial`` the initial guess is classical multidimensional scaling (MDS) of the range graph
  (missing pairs completed by shortest paths), refined by stress majorization (SMACOF) on the measured pairs and
  rotated/reflected/translated onto the known anchors (Procrustes).
* ``--loss huber|cauchy`` (LM and the neighbourhood solvers) down-weights ranges whose error exceeds about
  ``--loss-scale-m`` metres, so NLOS ranges that are metres too long stop pulling the solution (``rms_cost`` still
  reports the plain cost).
* ``--heights HEIGHTS.csv`` (``id,z_m``) holds those anchors' heights fixed and solves their horizontal position
  from the 3-D ranges — the remedy for the mirror ambiguity of anchors mounted in one plane (under a ceiling).
  A 3-D solve of a nearly planar network without it prints a warning.
* LM in metres: the robust fit of every link from several starts (the lowest cost wins) before the exclusions;
  exclusions that fit all the links much worse are rejected; ``--delay-sigma-m`` (default 0.015 m) widens the
  reported σ by the antenna delays left after the common offset (:mod:`distnav.models.uwb.precision`);
  ``--reliability-limit-m`` (default 0.3 m): an anchor that one link's undetectable bias (Baarda's MDB) would move
  further than that and 3σ is reported weak (:mod:`distnav.models.uwb.reliability`).
* The distributed solvers' σ are node-local: every anchor's 2-hop sub-network covariance, with the delays
  considered there (:mod:`distnav.algorithms.ranging.precision`; ``summary.json`` names the kind and counts its
  messages).

* ``--range-offsets common|per_anchor`` (every solver, metres objective) estimates one range offset or per-anchor
  antenna delays with the positions; ``common_delays`` (LM only, else exit 2) both: a common offset without a prior
  and delays about it, prior σ ``--offset-prior-sigma-m`` or with ``--estimate-offset-prior`` from the residuals
  (:mod:`distnav.algorithms.ranging.lm`; ``offsets.csv``: each anchor's ``c/2 + b_i``, ``summary.json``: ``c``);
  ``auto`` (default): :attr:`~distnav.models.uwb.field.FieldOptions.offsets_used` (docs/uwb.md, "Antenna delays").

Outputs in OUT_DIR: ``positions.csv`` (every anchor, with its accuracy radius and whether it meets
``--required-accuracy-m``), ``links.csv``, ``summary.json`` (``run``: the verdict), ``positions.png``, when offsets
were estimated ``offsets.csv`` (``id,offset_m,sigma_m``) and, when the ranges cannot tell the network from its
mirror image, ``positions_mirror.csv`` (the other map).

Exit codes (:mod:`distnav.models.uwb.verdict`):
  0  every anchor meets --required-accuracy-m (default 0.3 m; its radius holds the errors of all anchors jointly
     with 99 % probability by the reported σ, and it is not weak): the map can be used
  1  unusable: diverged (no positions written), or the log is inconsistent with the model (more than 25 % of the
     links excluded, exclusions and the robust fit disagree everywhere, or ranges 5 × noisier than --sigma-m)
  2  bad input or a refused geometry (nothing solved)
  3  a usable map, but the listed anchors do not meet --required-accuracy-m (weak, too large a radius, unsolved)
  4  ambiguous: the network and its mirror image (or an anchor and its flip) fit the ranges alike; both maps
     written (positions.csv, positions_mirror.csv)
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Any

import numpy as np

from distnav.algorithms.ranging.csg import SOLVERS
from distnav.algorithms.ranging.losses import LOSSES
from distnav.algorithms.ranging.objective import DELAY_MODES
from distnav.commands import add_backend_arguments
from distnav.commands.uwb_checks import (
    april_known_ids,
    check_applicable,
    check_gauge,
    check_initial_distinct,
    check_known_spelling,
    every_anchor,
    held_heights,
    validate_options,
)
from distnav.commands.uwb_outputs import (
    communication_entry,
    plot,
    positions_table,
    report,
    write_links,
    write_mirror_positions,
    write_offsets,
)
from distnav.errors import DataFileError, ModelError
from distnav.exchange import make_exchange
from distnav.formats.uwb.io import (
    CombinedRanges,
    check_units,
    combine_ranges,
    read_positions,
    read_ranges,
    single_link_anchors,
)
from distnav.models.uwb.field import (
    DELAY_SIGMA_M,
    RELIABILITY_LIMIT_M,
    FieldOptions,
    FieldSolution,
    gather_cost,
    prepare,
)
from distnav.models.uwb.geometry import planarity
from distnav.models.uwb.initial import classical_mds, height_spread_ratio, mds_initial_guess, smacof  # noqa: F401
from distnav.models.uwb.mirror import solve_with_mirror_test
from distnav.models.uwb.problems import RangingProblem, build_problem, rmse_m
from distnav.models.uwb.verdict import EXIT_NOT_ACCURATE, EXIT_OK, REQUIRED_ACCURACY_M, RunVerdict, run_verdict
from distnav.options import add_size_option, fields_from_args, int_up_to, output_folder, positive_float
from distnav.output import atomic_write_text

__all__ = [
    "register",
    "classical_mds",
    "smacof",
    "mds_initial_guess",
    "planarity",
    "height_spread_ratio",
    "solve_range_log",
    "write_april_csvs",
]

PLANAR_RATIO = 0.05
#: The most ``--iterations`` (refused at parse time above it): docs/benchmarks.md measures an N-CSG-TBLS iteration at
#: 58 ms on 10,000 anchors.
ITERATIONS = int_up_to(100_000, "an iteration of 10,000 anchors takes ≈ 58 ms: 100,000 are ≈ 1.6 h")


def default_loss(solver: str) -> str:
    """The solver's own default loss: ``linear`` for CSG (its only one), ``cauchy`` for LM and the neighbourhood
    solvers."""
    return "linear" if solver.upper() == "CSG" else "cauchy"


def register(subparsers: Any) -> None:
    """Add ``distnav uwb solve`` and ``distnav uwb import-april`` to the CLI."""
    uwb = subparsers.add_parser("uwb", help="UWB anchor self-localization from inter-anchor range logs")
    sub = uwb.add_subparsers(dest="uwb_command", required=True)
    s = sub.add_parser(
        "solve",
        help="estimate anchor positions from RANGES.csv and the known anchors",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    _add_file_arguments(s)
    _add_model_arguments(s)
    _add_test_arguments(s)
    _add_run_arguments(s)
    add_backend_arguments(s)
    s.set_defaults(func=_handler)
    _add_import_april(sub)


def _add_file_arguments(s: argparse.ArgumentParser) -> None:
    """``uwb solve``'s input files."""
    s.add_argument("--ranges", type=Path, required=True, help="CSV a,b,range_m (many rows per pair allowed)")
    s.add_argument("--known", type=Path, required=True, help="CSV id,x_m,y_m,z_m of the fixed (known) anchors")
    s.add_argument("--initial", type=Path, help="CSV id,x_m,y_m,z_m initial guess (default: MDS of the ranges)")
    s.add_argument("--truth", type=Path, help="CSV id,x_m,y_m,z_m true positions, for rmse_m")
    s.add_argument("--heights", type=Path, help="CSV id,z_m heights to hold fixed (anchors under a ceiling)")


def _add_model_arguments(s: argparse.ArgumentParser) -> None:
    """``uwb solve``'s solver, objective, loss and range model."""
    s.add_argument(
        "--solver",
        default="LM",
        type=str.upper,
        choices=list(SOLVERS),
        help="LM (centralized, default) or a distributed solver of paper 002",
    )
    s.add_argument(
        "--objective",
        default="metres",
        choices=["metres", "squared"],
        help="residual in metres e = |r_a - r_b| - d (default) or the paper's squared form",
    )
    s.add_argument(
        "--loss",
        default=None,
        choices=list(LOSSES),
        help="robust loss (default: cauchy for LM and the N-CSG/N-CLM solvers, linear for CSG, which has no other)",
    )
    s.add_argument(
        "--loss-scale-m",
        type=float,
        default=0.3,
        help="range error (m) beyond which the robust loss down-weights a range (default 0.3)",
    )
    s.add_argument("--sigma-m", type=float, default=0.1, help="a-priori range σ in metres (default 0.1)")


def _add_test_arguments(s: argparse.ArgumentParser) -> None:
    """``uwb solve``'s link tests, precision, reliability and verdict."""
    s.add_argument(
        "--no-exclude",
        dest="exclude",
        action="store_false",
        help="test the links but exclude none (default: exclude the worst link while it fails its "
        "w-test and the network stays determined, and re-solve)",
    )
    s.add_argument("--level", type=float, default=0.001, help="false-alarm probability of one link test (0.001)")
    s.add_argument(
        "--range-offsets",
        default="auto",
        choices=["auto", "none", "common", "per_anchor", "common_delays"],
        help="estimate a common range offset, per-anchor antenna delays, or both (common_delays, LM only; metres "
        "objective); auto (default): common with the metres objective, none with the squared one",
    )
    s.add_argument(
        "--offset-prior-sigma-m",
        type=float,
        default=0.1,
        help="prior σ of each per-anchor delay (per_anchor: about 0; common_delays: about the common offset; "
        "m, default 0.1)",
    )
    s.add_argument(
        "--estimate-offset-prior",
        action="store_true",
        help="LM with per_anchor or common_delays: estimate the delays' prior σ from the residuals (variance "
        "components), starting from --offset-prior-sigma-m",
    )
    s.add_argument(
        "--delay-sigma-m",
        type=float,
        default=DELAY_SIGMA_M,
        help="σ (m) of each anchor's antenna delay left after the common offset, admitted in the "
        f"reported σ without estimating it (metres objective, offsets auto/none/common; LM and "
        f"the distributed solvers; default {DELAY_SIGMA_M}, 0 = off)",
    )
    s.add_argument(
        "--reliability-limit-m",
        type=float,
        default=RELIABILITY_LIMIT_M,
        help="report an anchor weak when one link's minimal detectable bias, undetected, would move "
        f"it more than this (m) and 3σ (external reliability, every solver; default {RELIABILITY_LIMIT_M}, "
        "0 = off)",
    )
    s.add_argument(
        "--required-accuracy-m",
        type=positive_float,
        default=REQUIRED_ACCURACY_M,
        help="the accuracy (m) every anchor must meet for exit 0: its radius (99 %% of all anchors jointly, from "
        f"the reported σ) within it and not weak (default {REQUIRED_ACCURACY_M}); exit 3 lists the anchors that "
        "do not",
    )


def _add_run_arguments(s: argparse.ArgumentParser) -> None:
    """``uwb solve``'s geometry switch, iterations, input strictness and output folder."""
    s.add_argument(
        "--allow-planar-3d",
        action="store_true",
        help="solve a nearly planar network in 3-D with free heights anyway (refused by default)",
    )
    s.add_argument(
        "--no-refine",
        dest="refine",
        action="store_false",
        help="distributed solvers: stop after the neighbour iterations, without the final distributed "
        "LM phase that takes them to LM's solution (it needs a few network-wide sums per round; "
        "default: run it with the metres objective)",
    )
    add_size_option(s, "--iterations", ITERATIONS, default=500, help="iterations (default 500)")
    s.add_argument(
        "--strict",
        action="store_true",
        help="refuse a range log with a negative, zero or non-finite sample (default: drop and count)",
    )
    s.add_argument("--out", type=output_folder, required=True, help="output folder")


def _add_import_april(sub: Any) -> None:
    """``uwb import-april``."""
    imp = sub.add_parser(
        "import-april",
        help="convert an APRIL DW1000 log (../shared/data/uwb/april-dw1000-8node) to ranges.csv, known.csv, truth.csv",
    )
    imp.add_argument("log", type=Path, help="dataset4.txt or dataset5.txt")
    imp.add_argument("--known", default="8,12,54,87", help="comma-separated known node ids (default 8,12,54,87)")
    imp.add_argument(
        "--delays",
        default="manual",
        choices=["manual", "default"],
        help="subtract the lab's hand-calibrated antenna delays (default) or one 0.516 µs for all",
    )
    imp.add_argument("--out", type=output_folder, required=True, help="output folder")
    imp.set_defaults(func=_import_april)


def write_april_csvs(log: Path, out: Path, *, known: list[int], delays: str = "manual") -> dict[str, Path]:
    """Write ``ranges.csv``, ``known.csv`` and ``truth.csv`` of one APRIL log into ``out``
    (:func:`distnav.formats.uwb.april.april_csv_texts`); returns ``{stem: path}``."""
    from distnav.formats.uwb.april import april_csv_texts

    texts = april_csv_texts(log, known=known, delays=delays)
    o = Path(out)
    o.mkdir(parents=True, exist_ok=True)
    files = {stem: o / f"{stem}.csv" for stem in texts}
    for stem, text in texts.items():
        atomic_write_text(files[stem], text)
    return files


def _import_april(args: argparse.Namespace) -> int:
    from distnav.formats.uwb.april import TRUTH_FT

    known = april_known_ids(args.known, list(TRUTH_FT))
    files = write_april_csvs(args.log, args.out, known=known, delays=args.delays)
    print("wrote " + ", ".join(str(f) for f in files.values()))
    return 0


# ---------------------------------------------------------------------- the solve
def solve_range_log(
    ranges: Path,
    known: Path,
    *,
    initial: Path | None = None,
    truth: Path | None = None,
    heights: Path | None = None,
    options: FieldOptions | None = None,
    backend: str = "inprocess",
    strict: bool = False,
) -> tuple[FieldSolution, CombinedRanges, dict[str, Any]]:
    """Read the files, check the geometry, solve with QC; returns ``(solution, ranges, summary)`` (no files).

    A distributed solver runs on an exchange of ``backend`` (``"mpi"`` under ``mpiexec``); LM is centralized."""
    opts = options or FieldOptions()
    validate_options(opts)
    log = read_ranges(ranges, strict=strict)
    comb = combine_ranges(log)
    known_pos, dim = read_positions(known)
    units_note, units_warning = check_units(comb, known_pos, where=str(ranges))
    ids = log.ids
    index = {k: i for i, k in enumerate(ids)}
    unused_known = [k for k in known_pos if k not in index]
    # dropped samples: read_ranges has logged them (the CLI shows that line); summary.json counts them itself
    warnings: list[str] = []
    warnings += single_link_anchors(comb) + ([units_warning] if units_warning else [])
    check_known_spelling(known, ranges, unused_known, ids)
    if unused_known:
        warnings.append(f"known anchors without ranges are ignored: {', '.join(unused_known[:10])}")
    held = held_heights(heights, known, ranges, dim=dim, ids=index, known_pos=known_pos)
    fixed = {k: v for k, v in known_pos.items() if k in index}
    if not fixed:
        raise DataFileError(
            f"{known}: none of the known anchors ({', '.join(unused_known[:10])}) appears in "
            f"{ranges} (whose anchors are {', '.join(ids[:10])}{' …' if len(ids) > 10 else ''})"
        )
    truth_m = every_anchor(truth, "truth", ids, dim, known) if truth is not None else None
    problem = build_problem(
        ids,
        list(comb.pairs),
        comb.range_m,
        fixed=fixed,
        dim=dim,
        held=held or None,
        truth_m=truth_m,
        name=Path(ranges).stem,
        check_determined=False,
    )
    check_gauge(problem)
    init = every_anchor(initial, "initial guess", ids, dim, known) if initial is not None else None
    if initial is not None and init is not None:
        check_initial_distinct(initial, ids, init, fixed)
    init_source = (
        str(initial)
        if initial is not None
        else "classical MDS of the range graph + SMACOF, aligned to the known anchors"
    )
    sub, geometry = prepare(problem, initial_m=init, allow_planar_3d=opts.allow_planar_3d)
    exchange = None
    if opts.solver.upper() != "LM":

        def exchange(p: RangingProblem) -> Any:
            return make_exchange(p.graph, backend=backend)

    sol = solve_with_mirror_test(sub, opts, geometry, exchange)  # solve_field, + the mirror test if needed
    warnings += [i.message for i in sol.geometry.issues]
    summary = _summary(
        sol,
        opts,
        comb,
        log.range_m.size,
        log.n_dropped,
        dict(log.dropped),
        units_note,
        init_source,
        len(held),
        warnings,
    )
    return sol, comb, summary


def _summary(
    sol: FieldSolution,
    opts: FieldOptions,
    comb: CombinedRanges,
    n_ranges: int,
    n_dropped: int,
    dropped: dict[str, int],
    units_note: str,
    init_source: str,
    n_held: int,
    warnings: list[str],
) -> dict[str, Any]:
    p = sol.problem
    res = sol.result
    usable = sol.status != "diverged"
    e = sol.residual_m
    rms = float(np.sqrt(np.mean(e[~sol.excluded] ** 2))) if usable and (~sol.excluded).any() else None
    prec = getattr(res, "precision", None)
    gather = gather_cost(p)
    offsets = getattr(res, "offsets_m", None)
    offsets_std = getattr(res, "offsets_std_m", None)
    return {
        "solver": opts.solver.upper(),
        "objective": sol.objective_used,
        "status": sol.status,
        "usable": sol.status in ("converged", "max_iterations", "weakly_determined"),
        "message": sol.message,
        "iterations": sol.iterations,
        "iterations_counted": (
            "LM iterations, every fit of the workflow"
            if opts.solver.upper() == "LM"
            else "neighbour iterations plus the final distributed LM phase's rounds, every fit of the workflow"
        ),
        "rmse_m": rmse_m(p, sol.positions_m) if usable and p.truth_m is not None else None,
        "range_residual_rms_m": rms,
        "rms_cost": float(np.sqrt(np.mean(p.residuals(sol.positions_m) ** 2))) if usable else None,
        "loss": opts.loss,
        "loss_used": "cauchy_long" if opts.nlos_aware else opts.loss,  # one-sided: NLOS only lengthens a range
        "loss_scale_m": opts.loss_scale_m if opts.loss != "linear" else None,
        "sigma_m": opts.sigma_m,
        "variance_factor": None if prec is None else prec.variance_factor,
        "delay_sigma_m_considered": opts.delay_sigma_m if opts.considers_delays else None,
        "precision_kind": sol.precision_kind,
        "test_level": opts.level,
        "critical_value": sol.critical_value,
        "n_flagged": int(sol.flagged.sum()),
        "n_excluded": int(sol.excluded.sum()),
        "excluded_links": [[p.ids[p.meas_a[k]], p.ids[p.meas_b[k]]] for k in np.flatnonzero(sol.excluded)],
        "range_offsets": opts.offsets_used,
        "offsets_m": None if offsets is None else np.asarray(offsets).tolist(),
        "offsets_std_m": None if offsets_std is None else np.asarray(offsets_std).tolist(),
        "common_offset_m": getattr(res, "settings", {}).get("common_offset_m"),  # common_delays: c (offsets: c/2 + b_i)
        # the delays' prior σ used (common_delays, or estimated: --estimate-offset-prior) and whether it was estimated
        "offset_prior_sigma_m": getattr(res, "settings", {}).get("offset_prior_sigma_m"),
        "offset_prior_estimated": getattr(res, "settings", {}).get("offset_prior_estimated"),
        "geometry": sol.geometry.as_dict(),
        "unsolved": list(sol.geometry.unsolved),
        "weakly_determined_anchors": list(sol.weak),
        "weak_reasons": dict(sol.weak_reasons),
        "reliability": sol.reliability,
        "n_anchors": len(sol.geometry.ids),
        "n_solved": p.n_anchors,
        "n_known": int(p.fixed.sum()),
        "n_heights_held": n_held,
        "n_pairs": len(comb.pairs),
        "n_ranges": int(n_ranges),
        "n_dropped_samples": n_dropped,
        "dropped_samples": dropped,
        "units_check": units_note,
        "range_combination": "median of the samples of each pair",
        "initial_guess": init_source,
        "communication": communication_entry(sol, opts, gather),
        "messages": sol.messages,
        "bytes": sol.bytes,
        "warnings": warnings,
    }


@np.errstate(over="ignore", invalid="ignore")  # a diverged run's summary reads huge estimates
def _handler(args: argparse.Namespace) -> int:
    opts = FieldOptions(
        **fields_from_args(args, FieldOptions, but=("loss", "solver_options")),
        loss=args.loss or default_loss(args.solver),
        solver_options=({} if args.refine else {"refine": False})
        | ({"estimate_offset_prior": True} if args.estimate_offset_prior else {}),
    )
    if args.estimate_offset_prior and (opts.solver.upper() != "LM" or opts.range_offsets not in DELAY_MODES):
        raise ModelError(
            "--estimate-offset-prior estimates the per-anchor delays' prior σ: it needs --solver LM and "
            f"--range-offsets per_anchor or common_delays (got --solver {opts.solver}, --range-offsets "
            f"{opts.range_offsets})"
        )
    if not args.refine and opts.solver == "LM":
        raise ModelError("--no-refine applies to the distributed solvers (--solver N-CLM, N-CSG-TBLS, ...), not to LM")
    validate_options(opts)
    check_applicable(opts)
    out = Path(args.out)
    if out.exists() and not out.is_dir():
        raise DataFileError(f"{out}: --out must be a folder, and this is a file")
    sol, comb, summary = solve_range_log(
        args.ranges,
        args.known,
        initial=args.initial,
        truth=args.truth,
        heights=args.heights,
        options=opts,
        backend=getattr(args, "backend", "inprocess"),
        strict=args.strict,
    )
    from distnav.output import atomic_write_json, is_file_writer

    verdict = run_verdict(sol, args.required_accuracy_m)
    summary = with_verdict(summary, verdict)
    usable = sol.status != "diverged"
    if is_file_writer():  # under MPI only rank 0 writes (and prints)
        for w in summary["warnings"]:
            print(f"warning: {w}", file=sys.stderr)
        out.mkdir(parents=True, exist_ok=True)
        atomic_write_json(out / "summary.json", summary)
        if not usable:  # the estimates are not a result; write no positions
            print(
                f"error: {sol.message} (status {sol.status}); no positions written, see {out / 'summary.json'}",
                file=sys.stderr,
            )
            return verdict.exit_code
        positions_table(out / "positions.csv", sol, verdict)
        write_mirror_positions(out / "positions_mirror.csv", sol)
        write_links(out / "links.csv", sol, comb)
        write_offsets(out / "offsets.csv", sol)
        try:
            plot(out / "positions.png", sol)
        except ImportError as exc:  # pragma: no cover - plot extra missing
            print(f"warning: no plot ({exc})", file=sys.stderr)
        report(summary, sol, verdict, out)
        return verdict.exit_code
    return EXIT_OK  # another MPI rank: rank 0 speaks for the run (a non-zero exit here would abort it mid-write)


def with_verdict(summary: dict[str, Any], verdict: RunVerdict) -> dict[str, Any]:
    """``summary`` with the run's verdict: ``status`` the run's (``solver_status`` the solve's), ``usable`` (exit 0
    or 3: a map to use, with or without anchors short of the accuracy) and ``run`` (the verdict, exit code)."""
    return {
        **summary,
        "status": verdict.status,
        "solver_status": summary["status"],
        "usable": verdict.exit_code in (EXIT_OK, EXIT_NOT_ACCURATE),
        "run": verdict.as_dict(),
    }
