"""What ``distnav uwb solve`` writes and prints: ``positions.csv`` (with each anchor's accuracy radius and whether
it meets the required accuracy), ``positions_mirror.csv``, ``links.csv``, ``offsets.csv``, ``positions.png`` and the
lines of the verdict (:mod:`distnav.models.uwb.verdict`)."""

from __future__ import annotations

import math
import sys
from pathlib import Path
from typing import Any

import numpy as np

from distnav.algorithms.result import CommComparison, compare_with_gather
from distnav.formats.uwb.io import CombinedRanges, format_positions
from distnav.models.uwb.communication import RANGES_DATA, range_bytes_per_anchor
from distnav.models.uwb.field import FieldOptions, FieldSolution
from distnav.models.uwb.verdict import RunVerdict
from distnav.output import atomic_write_text

__all__ = [
    "communication_entry",
    "gather_comparison",
    "map_accuracy_line",
    "positions_table",
    "report",
    "write_links",
    "write_mirror_positions",
    "write_offsets",
    "plot",
]


def write_links(path: Path, sol: FieldSolution, comb: CombinedRanges) -> None:
    """``links.csv``: a, b, samples, median range, MAD, residual, w, flagged, excluded (one row per pair)."""
    p = sol.problem
    stats = {k: (int(c), float(m)) for k, c, m in zip(comb.pairs, comb.count, comb.mad_m, strict=True)}
    rows = ["a,b,samples,median_range_m,mad_m,residual_m,w,flagged,excluded"]
    for k in range(p.n_meas):
        a, b = p.ids[p.meas_a[k]], p.ids[p.meas_b[k]]
        cnt, mad = stats.get((a, b)) or stats.get((b, a)) or (0, float("nan"))
        rows.append(
            f"{a},{b},{cnt},{p.range_m[k]:.4f},{mad:.4f},{sol.residual_m[k]:.4f},{sol.w[k]:.3f},"
            f"{int(sol.flagged[k])},{int(sol.excluded[k])}"
        )
    atomic_write_text(path, "\n".join(rows) + "\n")


def write_offsets(path: Path, sol: FieldSolution) -> None:
    """``offsets.csv`` (only when offsets were estimated): ``id,offset_m,sigma_m`` — one row ``common`` or one per
    anchor (its antenna delay: every range it takes part in reads ``b_a + b_b`` long); σ a-posteriori."""
    off = getattr(sol.result, "offsets_m", None)
    if off is None:
        return
    std = getattr(sol.result, "offsets_std_m", None)
    std = np.full(len(off), np.nan) if std is None else np.asarray(std)
    names = ["common"] if len(off) == 1 else list(sol.problem.ids)
    rows = ["id,offset_m,sigma_m"] + [f"{k},{o:.6f},{s:.6f}" for k, o, s in zip(names, off, std, strict=True)]
    atomic_write_text(path, "\n".join(rows) + "\n")


def positions_table(path: Path, sol: FieldSolution, verdict: RunVerdict | None = None) -> None:
    """``positions.csv``: every anchor with σ per axis, a status (known, estimated, weak, ambiguous, unsolved) and,
    for a weak one, why (``weak_reason``: misfit, thin, reliability — which link would go undetected and how far
    it would move the anchor —, cut — a part placed by fewer checks than the exclusions took off its cut —, untested
    or disagree; no commas) and, with a ``verdict``, ``accuracy_m`` (its radius, :mod:`distnav.models.uwb.verdict`)
    and ``meets_required`` (1 / 0; empty for a known anchor)."""
    p = sol.problem
    dim = p.dim
    axes = ["x", "y", "z"][:dim]
    rows = [
        "id,"
        + ",".join(f"{a}_m" for a in axes)
        + ","
        + ",".join(f"s{a}_m" for a in axes)
        + ",status,weak_reason,accuracy_m,meets_required"
    ]
    index = {k: i for i, k in enumerate(p.ids)}
    amb = sol.geometry.ambiguous_anchors()
    for name in sol.geometry.ids:
        if name not in index:
            rows.append(name + "," * (2 * dim) + ",unsolved,,,0")
            continue
        i = index[name]
        st = "known" if p.fixed[i] else ("ambiguous" if name in amb else "weak" if name in sol.weak else "estimated")
        rows.append(
            name
            + ","
            + ",".join(f"{v:.6f}" for v in sol.positions_m[i])
            + ","
            + ",".join(f"{v:.6f}" for v in sol.sigma_m[i])
            + f",{st},"
            + (sol.weak_reasons.get(name, "").replace(",", ";") if st == "weak" else "")
            + _verdict_columns(name, verdict)
        )
    atomic_write_text(path, "\n".join(rows) + "\n")


def _verdict_columns(name: str, verdict: RunVerdict | None) -> str:
    if verdict is None or name not in verdict.accuracy_m:
        return ",,"
    return f",{verdict.accuracy_m[name]:.4f},{int(name not in verdict.failing)}"


def write_mirror_positions(path: Path, sol: FieldSolution) -> None:
    """``positions_mirror.csv`` (``id,x_m,y_m[,z_m]``): the other side's map when the mirror test cannot choose."""
    if sol.mirror_positions_m is None:
        return
    atomic_write_text(path, format_positions(list(sol.problem.ids), sol.mirror_positions_m))


def plot(path: Path, sol: FieldSolution) -> None:
    from distnav.output import pyplot

    plt = pyplot()
    from matplotlib.collections import LineCollection
    from matplotlib.patches import Ellipse

    p, est = sol.problem, sol.positions_m
    fig, ax = plt.subplots(figsize=(8, 6))
    seg = np.stack([est[p.meas_a, :2], est[p.meas_b, :2]], axis=1)
    res = np.abs(np.nan_to_num(sol.residual_m))
    kept = ~sol.excluded
    lc = LineCollection(list(seg[kept]), array=res[kept], cmap="viridis_r", linewidths=1.2, zorder=1)
    ax.add_collection(lc)
    fig.colorbar(lc, ax=ax, label="|range residual| [m]")
    if sol.excluded.any():
        ax.add_collection(
            LineCollection(
                list(seg[sol.excluded]),
                colors="tab:red",
                linestyles="dashed",
                linewidths=1.0,
                zorder=1,
                label="excluded (NLOS?)",
            )
        )
    if p.truth_m is not None:
        t = p.truth_m
        ax.plot(t[:, 0], t[:, 1], "x", color="tab:green", label="truth", zorder=2)
    e = p.estimated
    ax.plot(est[e, 0], est[e, 1], "o", color="tab:blue", ms=4, label="estimated", zorder=3)
    ax.plot(est[~e, 0], est[~e, 1], "^", color="k", ms=8, label="known", zorder=4)
    scale = 0.0
    if sol.covariance_m2 is not None:
        cov = sol.covariance_m2[:, :2, :2]
        sig = np.sqrt(np.maximum(np.trace(cov, axis1=1, axis2=2), 0.0))
        span = float(np.ptp(est[:, :2], axis=0).max())
        scale = max(1.0, round(0.03 * span / max(float(sig[e].max(initial=0.0)), 1e-9)))  # ellipses visible
        for i in np.flatnonzero(e):
            w, v = np.linalg.eigh(cov[i])
            ang = float(np.degrees(np.arctan2(v[1, 1], v[0, 1])))
            ax.add_patch(
                Ellipse(
                    tuple(est[i, :2]),
                    2 * 2 * scale * np.sqrt(max(w[1], 0.0)),
                    2 * 2 * scale * np.sqrt(max(w[0], 0.0)),
                    angle=ang,
                    fill=False,
                    color="tab:orange",
                    lw=0.8,
                    zorder=3,
                )
            )
    for idx, name in enumerate(p.ids):
        ax.annotate(name, est[idx, :2], fontsize=6, xytext=(3, 3), textcoords="offset points")
    ax.set_aspect("equal")
    ax.autoscale_view()
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    ax.legend(fontsize=7, loc="best")
    ell = f"; 2σ ellipses × {scale:g}" if scale else ""
    ax.set_title(
        f"{p.n_anchors} anchors, {p.links.shape[0]} links ({int(sol.excluded.sum())} excluded){ell}", fontsize=9
    )
    fig.savefig(path, dpi=110, bbox_inches="tight")
    plt.close(fig)


def report(summary: dict[str, Any], sol: FieldSolution, verdict: RunVerdict, out: Path) -> None:
    """The lines ``uwb solve`` prints: one of the solve, then what the verdict means for the user."""
    rm = summary["rmse_m"]
    rr = summary["range_residual_rms_m"]
    print(
        f"{summary['solver']} ({summary['objective']}, {summary['loss_used']}): {summary['iterations']} iterations, "
        f"status {summary['status']}, {summary['n_excluded']} link(s) excluded"
        + (f", range residual RMS {rr:.3f} m" if rr is not None else "")
        + (f", RMSE {rm:.3f} m" if rm is not None else "")
        + f" -> {out}"
    )
    comparison = (summary.get("communication") or {}).get("comparison")
    if comparison is not None:
        print(comparison["line"])
    req = verdict.required_accuracy_m
    if verdict.verdict == "ok":
        print(f"every anchor meets the required accuracy of {req:g} m (exit 0)")
        return
    if verdict.verdict == "ambiguous":
        print(
            f"error: the solution is ambiguous ({sol.message}); positions written with status 'ambiguous'"
            + ("; the other map in positions_mirror.csv" if sol.mirror_positions_m is not None else ""),
            file=sys.stderr,
        )
        return
    if verdict.verdict == "unusable":
        print(
            "error: the map is unusable: " + "; ".join(verdict.reasons) + " (positions written for diagnosis only)",
            file=sys.stderr,
        )
        return
    n = len(verdict.failing)
    print(
        f"warning: {n} anchor(s) do not meet the required accuracy of {req:g} m (exit 3; positions.csv "
        "meets_required, summary.json run.failing):",
        file=sys.stderr,
    )
    for k, why in list(verdict.failing.items())[:20]:
        print(f"  {k}: {why}", file=sys.stderr)
    if n > 20:
        print(f"  … and {n - 20} more", file=sys.stderr)
    print(map_accuracy_line(verdict), file=sys.stderr)


def map_accuracy_line(verdict: RunVerdict) -> str:
    """What the map does give (issue 28 item 2): the accuracy its anchors meet apart from the blocking ones (weak,
    ambiguous, unsolved), and what to do about those."""
    acc, blocking = verdict.map_accuracy_m, verdict.blocking
    if acc is None:
        return (
            "  no anchor's accuracy can be stated: " + ", ".join(blocking[:12]) + " need more links or a known anchor"
        )
    bound = f"{math.ceil(acc * 1000.0) / 1000.0:.3f}"
    if not blocking:
        return (
            f"  this map meets {bound} m (every anchor within its radius, 99 % jointly): "
            f"--required-accuracy-m {bound} exits 0"
        )
    return (
        f"  the other anchors meet {bound} m (99 % jointly); {', '.join(blocking[:12])}"
        + (f" and {len(blocking) - 12} more" if len(blocking) > 12 else "")
        + " fail at any required accuracy (weak, ambiguous or unsolved: add links to them or a known anchor near them)"
    )


def communication_entry(sol: FieldSolution, opts: FieldOptions, gather: dict[str, Any]) -> dict[str, Any]:
    """``summary.json`` ``communication``: the distributed solve's messages and bytes beside the gather."""
    return {
        "distributed": {
            "solver": opts.solver.upper(),
            "messages": sol.messages,
            "bytes": sol.bytes,
            "precision_messages": sol.precision_messages,
            "precision_bytes": sol.precision_bytes,
            "final_lm_phase": getattr(sol.result, "settings", {}).get("refine"),
            "note": "every re-solve of the exclusion loop and the precision included"
            if opts.solver.upper() != "LM"
            else "LM is centralized: it needs the ranges gathered (below)",
        },
        "gather_at_one_anchor": gather,
        "comparison": None if opts.solver.upper() == "LM" else gather_comparison(sol).as_dict(),
    }


def gather_comparison(sol: FieldSolution) -> CommComparison:
    """The distributed solve's traffic (totals: the exclusion loop's re-solves and the precision included) beside
    gathering every range at one anchor over the range graph (each link's record held by its lower-numbered
    anchor, :data:`RANGE_RECORD_BYTES` each; issue 27)."""
    p = sol.problem
    return compare_with_gather(
        (sol.bytes, sol.messages),
        p.graph,
        range_bytes_per_anchor(p),
        data=RANGES_DATA,
        node_label="anchor",
        node_names=p.ids,
    )
