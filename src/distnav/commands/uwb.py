"""``distnav uwb solve``: anchor positions from a real (or simulated) inter-anchor range log.

    distnav uwb solve --ranges RANGES.csv --known KNOWN.csv [--initial INIT.csv] [--solver NAME]
                      [--truth TRUTH.csv] [--heights HEIGHTS.csv] [--loss linear|huber|cauchy]
                      [--loss-scale-m 0.3] [--iterations 500] [--backend inprocess|mpi] --out OUT_DIR

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

Outputs in OUT_DIR: ``positions.csv`` (every anchor), ``summary.json`` and ``positions.png``.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Any

import numpy as np

from distnav.algorithms.csg import SOLVERS, solve
from distnav.algorithms.nlsq import LOSSES
from distnav.commands import add_backend_arguments
from distnav.errors import DataFileError, ModelError
from distnav.exchange import make_exchange
from distnav.models.uwb.geometry import planarity
from distnav.models.uwb.initial import classical_mds, height_spread_ratio, mds_initial_guess, smacof
from distnav.models.uwb.io import (
    check_units,
    combine_ranges,
    read_heights,
    read_positions,
    read_ranges,
    single_link_anchors,
    write_positions,
)
from distnav.models.uwb.problems import RangingProblem, build_problem, rmse_m

__all__ = ["register", "classical_mds", "smacof", "mds_initial_guess", "planarity", "height_spread_ratio",
           "solve_range_log"]

PLANAR_RATIO = 0.05


def register(subparsers: Any) -> None:
    """Add ``distnav uwb solve`` to the CLI."""
    uwb = subparsers.add_parser("uwb", help="UWB anchor self-localization from inter-anchor range logs")
    sub = uwb.add_subparsers(dest="uwb_command", required=True)
    s = sub.add_parser("solve", help="estimate anchor positions from RANGES.csv and the known anchors",
                       description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    s.add_argument("--ranges", type=Path, required=True, help="CSV a,b,range_m (many rows per pair allowed)")
    s.add_argument("--known", type=Path, required=True, help="CSV id,x_m,y_m,z_m of the fixed (known) anchors")
    s.add_argument("--initial", type=Path, help="CSV id,x_m,y_m,z_m initial guess (default: MDS of the ranges)")
    s.add_argument("--truth", type=Path, help="CSV id,x_m,y_m,z_m true positions, for rmse_m")
    s.add_argument("--heights", type=Path, help="CSV id,z_m heights to hold fixed (anchors under a ceiling)")
    s.add_argument("--solver", default="LM", type=str.upper, choices=list(SOLVERS),
                   help="LM (centralized, default) or a distributed solver of paper 002")
    s.add_argument("--loss", default="linear", choices=list(LOSSES),
                   help="robust loss (LM and the N-CSG/N-CLM solvers; not CSG)")
    s.add_argument("--loss-scale-m", type=float, default=0.3,
                   help="range error (m) beyond which the robust loss down-weights a range (default 0.3)")
    s.add_argument("--iterations", type=int, default=500, help="iterations (default 500)")
    s.add_argument("--strict", action="store_true",
                   help="refuse a range log with a negative, zero or non-finite sample (default: drop and count)")
    s.add_argument("--out", type=Path, required=True, help="output folder")
    add_backend_arguments(s)
    s.set_defaults(func=_handler)


# ---------------------------------------------------------------------- the solve
def solve_range_log(ranges: Path, known: Path, *, initial: Path | None = None, truth: Path | None = None,
                    heights: Path | None = None, solver: str = "LM", loss: str = "linear",
                    loss_scale_m: float = 0.3, iterations: int = 500, backend: str = "inprocess",
                    strict: bool = False) -> tuple[RangingProblem, Any, dict[str, Any]]:
    """Read the files, build the problem, solve; returns ``(problem, result, summary)`` (no files written).

    A distributed solver runs on an exchange of ``backend`` (``"mpi"`` under ``mpiexec``); LM is centralized."""
    if loss != "linear" and solver.upper() == "CSG":
        raise ModelError(f"--loss {loss} is implemented for LM and the neighbourhood solvers, not CSG")
    if iterations < 1:
        raise ModelError(f"--iterations must be ≥ 1, got {iterations}")
    log = read_ranges(ranges, strict=strict)
    comb = combine_ranges(log)
    known_pos, dim = read_positions(known)
    units_note, units_warning = check_units(comb, known_pos, where=str(ranges))
    ids = log.ids
    index = {k: i for i, k in enumerate(ids)}
    unused_known = [k for k in known_pos if k not in index]
    warnings: list[str] = [log.drop_message()] if log.n_dropped else []
    warnings += single_link_anchors(comb) + ([units_warning] if units_warning else [])
    if unused_known:
        warnings.append(f"known anchors without ranges are ignored: {', '.join(unused_known[:10])}")
    held: dict[str, dict[int, float]] = {}
    if heights is not None:
        if dim != 3:
            raise DataFileError(f"{heights}: heights need a 3-D network, but {known} has no z_m column")
        hz, hline = read_heights(heights)
        for k, z in hz.items():
            if k not in index:
                raise DataFileError(f"{heights}:{hline[k]}: anchor {k!r} does not appear in {ranges}")
            if k not in known_pos:
                held[k] = {2: z}
    fixed = {k: v for k, v in known_pos.items() if k in index}

    def full_array(path: Path, what: str) -> np.ndarray:
        pos, d = read_positions(path)
        if d != dim:
            raise DataFileError(f"{path}: has {d}-D positions but {known} has {dim}-D")
        missing = [k for k in ids if k not in pos]
        if missing:
            raise DataFileError(f"{path}: {what} lacks anchor(s) {', '.join(repr(m) for m in missing[:10])}")
        return np.array([pos[k] for k in ids])

    truth_m = full_array(truth, "truth") if truth is not None else None
    problem = build_problem(ids, list(comb.pairs), comb.range_m, fixed=fixed, dim=dim, held=held or None,
                            truth_m=truth_m, name=Path(ranges).stem)
    if initial is not None:
        init = full_array(initial, "initial guess")
        init_source = str(initial)
    else:
        init = mds_initial_guess(problem)
        init_source = "classical MDS of the range graph + SMACOF, aligned to the known anchors"
    problem = problem.with_initial(init)
    if dim == 3 and not held:
        ratio = height_spread_ratio(problem)
        if ratio < PLANAR_RATIO:
            warnings.append(
                f"the network looks nearly planar (the known anchors' vertical/horizontal spread is {ratio:.3f} < "
                f"{PLANAR_RATIO}): a 3-D solve cannot tell above from below the anchors' plane and heights may come "
                f"out metres off; pass --heights HEIGHTS.csv (id,z_m) to hold the known mounting heights")
    options: dict[str, Any] = {}
    if solver.upper() != "CSG":
        options = {"loss": loss, "loss_scale_m": loss_scale_m}
    if solver.upper() != "LM":
        options["exchange"] = make_exchange(problem.graph, backend=backend)
    result = solve(problem, solver, iterations=iterations, **options)
    est = result.estimates
    g = problem.residuals(est)
    summary: dict[str, Any] = {
        "solver": solver.upper(),
        "iterations": int(result.iterations),
        "rms_cost": float(np.sqrt(np.mean(g * g))),
        "cost": float(g @ g),
        "rmse_m": rmse_m(problem, est) if truth_m is not None else None,
        "converged": bool(result.converged),
        "status": result.status,
        "messages": int(result.comm.messages),
        "bytes": int(result.comm.bytes),
        "message": result.message,
        "loss": loss,
        "loss_scale_m": loss_scale_m if loss != "linear" else None,
        "n_anchors": problem.n_anchors,
        "n_known": int(problem.fixed.sum()),
        "n_heights_held": len(held),
        "n_pairs": len(comb.pairs),
        "n_ranges": int(log.range_m.size),
        "n_dropped_samples": log.n_dropped,
        "dropped_samples": dict(log.dropped),
        "units_check": units_note,
        "range_combination": "median of the samples of each pair",
        "initial_guess": init_source,
        "range_residual_rms_m": float(np.sqrt(np.mean(
            (np.linalg.norm(est[problem.meas_a] - est[problem.meas_b], axis=1) - problem.range_m) ** 2))),
        "warnings": warnings,
    }
    return problem, result, summary


def _plot(path: Path, problem: RangingProblem, est: np.ndarray) -> None:
    from distnav.experiments.common import pyplot

    plt = pyplot()
    fig, ax = plt.subplots(figsize=(7, 6))
    lk = problem.links
    seg = np.full((lk.shape[0], 3, 2), np.nan)  # one NaN-separated polyline
    seg[:, 0], seg[:, 1] = est[lk[:, 0], :2], est[lk[:, 1], :2]
    ax.plot(seg[:, :, 0].ravel(), seg[:, :, 1].ravel(), "-", color="0.8", lw=0.6, zorder=1)
    if problem.truth_m is not None:
        t = problem.truth_m
        ax.plot(t[:, 0], t[:, 1], "x", color="tab:green", label="truth", zorder=2)
        for k in np.flatnonzero(problem.estimated):
            ax.plot([t[k, 0], est[k, 0]], [t[k, 1], est[k, 1]], "-", color="tab:red", lw=0.8, zorder=2)
    e = problem.estimated
    ax.plot(est[e, 0], est[e, 1], "o", color="tab:blue", ms=5, label="estimated", zorder=3)
    ax.plot(est[~e, 0], est[~e, 1], "^", color="k", ms=8, label="known", zorder=4)
    for idx, name in enumerate(problem.ids):
        ax.annotate(name, est[idx, :2], fontsize=6, xytext=(3, 3), textcoords="offset points")
    ax.set_aspect("equal")
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    ax.legend(fontsize=8)
    ax.set_title(f"{problem.n_anchors} anchors, {problem.links.shape[0]} measured pairs")
    fig.savefig(path, dpi=110, bbox_inches="tight")
    plt.close(fig)


@np.errstate(over="ignore", invalid="ignore")  # a diverged run's summary reads huge estimates
def _handler(args: argparse.Namespace) -> int:
    problem, result, summary = solve_range_log(
        args.ranges, args.known, initial=args.initial, truth=args.truth, heights=args.heights, solver=args.solver,
        loss=args.loss, loss_scale_m=args.loss_scale_m, iterations=args.iterations,
        backend=getattr(args, "backend", "inprocess"), strict=args.strict)
    from distnav.experiments.common import atomic_write_json, is_file_writer

    out = Path(args.out)
    if is_file_writer():  # under MPI only rank 0 writes (and prints)
        for w in summary["warnings"]:
            print(f"warning: {w}", file=sys.stderr)
        out.mkdir(parents=True, exist_ok=True)
        atomic_write_json(out / "summary.json", summary)
        if not result.usable:  # e.g. "diverged": the estimates are not a result; write no positions
            print(f"error: {result.message} (status {result.status}); no positions written, see "
                  f"{out / 'summary.json'}", file=sys.stderr)
            return 1
        write_positions(out / "positions.csv", problem.ids, result.estimates)
        try:
            _plot(out / "positions.png", problem, result.estimates)
        except ImportError as exc:  # pragma: no cover - plot extra missing
            print(f"warning: no plot ({exc})", file=sys.stderr)
    if not result.usable:
        return 1
    rm = summary["rmse_m"]
    print(f"{summary['solver']}: {summary['iterations']} iterations, rms_cost {summary['rms_cost']:.4g} m², "
          f"range residual RMS {summary['range_residual_rms_m']:.3f} m"
          + (f", RMSE {rm:.3f} m" if rm is not None else "") + f" -> {out}")
    return 0
