"""Figures of :mod:`distnav.experiments.admm` (paper 000 Figs. 3–5, the ρ sweep with Fig. 9-like per-node curves,
and the nonlinear range problem of §4.3), one function each, from the parts' result dicts."""

from __future__ import annotations

from typing import Any

import numpy as np

from distnav.algorithms.lsq.blue import LinearProblem, dual_function
from distnav.experiments.common import ExperimentContext, pyplot
from distnav.network.graph import Graph

#: marker, colour and label of each 2-node run of Figs. 3–4
STYLES = {
    "method_of_multipliers": ("o", "tab:red", "method of multipliers"),
    "admm_z0=3": ("s", "tab:green", "ADMM, z⁰ = 3"),
    "admm_z0=-7": ("^", "m", "ADMM, z⁰ = −7"),
}


def figures(
    ctx: ExperimentContext,
    a: dict[str, Any],
    b: dict[str, Any],
    c: dict[str, Any],
    d: dict[str, Any],
    *,
    problem: LinearProblem,
    two_node: dict[str, Any],
    iterations_2d: int,
) -> None:
    """Every figure of the ADMM experiment: parts (a)–(d) of :func:`distnav.experiments.admm.run`, with the
    2-node ``problem`` and its data ``two_node`` (a, R, y, W) of part (a), which ran ``iterations_2d`` steps."""
    _fig3_multipliers(ctx, a, problem, two_node)
    _fig4_admm_vs_multipliers(ctx, a, two_node, iterations_2d)
    _fig5_constraint_nodes(ctx, b)
    _fig9_rho(ctx, c)
    _figure_nonlinear(ctx, d)


def _dual_on_grid(prob: LinearProblem, W: float, U1: np.ndarray, U2: np.ndarray) -> np.ndarray:
    """``g(u)`` of the 2-node problem on a grid. For least squares ``g`` is an exact quadratic in ``u`` (eq. (10)
    with the minimizers (15) linear in ``u``), so 9 evaluations of :func:`dual_function` determine it; the fit is
    checked at a 10th point."""
    pts = [(a, b) for a in (-1.0, 0.0, 1.0) for b in (-1.0, 0.0, 1.0)]

    def basis(u1: np.ndarray, u2: np.ndarray) -> np.ndarray:
        return np.stack([np.ones_like(u1), u1, u2, u1 * u1, u1 * u2, u2 * u2], axis=-1)

    vals = np.array([dual_function(prob, np.array([[a], [b]]), W) for a, b in pts])
    coef = np.linalg.lstsq(basis(*np.array(pts).T), vals, rcond=None)[0]
    check = dual_function(prob, np.array([[2.5], [-1.5]]), W)
    if abs(float(basis(np.array(2.5), np.array(-1.5)) @ coef) - check) > 1e-9 * (1 + abs(check)):
        raise RuntimeError("the dual function is not quadratic: the grid fit failed")
    grid: np.ndarray = basis(U1, U2) @ coef
    return grid


def _primal_axes(ax: Any, a: dict[str, Any], two_node: dict[str, Any], keys: list[str]) -> None:
    """The primal plane of the 2-node problem: contours of f1(x1) + f2(x2), primal and dual feasibility, the runs
    ``keys`` and the least-squares solution."""
    aa, RR, yy = (np.array(two_node[k]) for k in ("a", "R", "y"))
    xh = a["x_hat"]
    g1 = np.linspace(xh - 4, xh + 4, 200)
    X1, X2 = np.meshgrid(g1, g1)
    F = 0.5 * (yy[0] - aa[0] * X1) ** 2 / RR[0] + 0.5 * (yy[1] - aa[1] * X2) ** 2 / RR[1]
    # dual feasibility: a1(a1 x1 − y1)/R1 + a2(a2 x2 − y2)/R2 = 0
    x2_dual = (aa[1] * yy[1] / RR[1] - aa[0] * (aa[0] * g1 - yy[0]) / RR[0]) / (aa[1] ** 2 / RR[1])
    ax.contour(X1, X2, F, levels=15, colors="0.7", linewidths=0.7)
    ax.plot(g1, g1, "b-", lw=1.2, label="primal feasibility x₁ = x₂")
    ax.plot(g1, x2_dual, "k-", lw=1.2, label="dual feasibility")
    for key in keys:
        mk, col, lab = STYLES[key]
        pts = np.array(a[key]["x"])
        ax.plot(pts[:, 0], pts[:, 1], mk, color=col, ms=5, label=lab)
    ax.plot([xh], [xh], "r*", ms=14, label="least-squares solution")
    ax.set_xlim(g1[0], g1[-1])
    ax.set_ylim(g1[0], g1[-1])
    ax.set_xlabel("x₁")
    ax.set_ylabel("x₂")
    ax.set_aspect("equal")
    ax.legend(fontsize=7)


def _fig3_multipliers(ctx: ExperimentContext, a: dict[str, Any], prob: LinearProblem, two_node: dict[str, Any]) -> None:
    """Fig. 3: the method of multipliers in the primal and the dual plane."""
    fig, axes = pyplot().subplots(1, 2, figsize=(11, 5))
    _primal_axes(axes[0], a, two_node, ["method_of_multipliers"])
    uh = np.array(a["u_hat"])
    us = np.linspace(-4, 4, 81)
    U1, U2 = np.meshgrid(uh[0] + us, uh[1] + us)
    G = _dual_on_grid(prob, two_node["W"], U1, U2)
    axes[1].contour(U1, U2, G, levels=15, colors="0.7", linewidths=0.7, linestyles="solid")
    upath = np.vstack([[0.0, 0.0], np.array(a["method_of_multipliers"]["u"])])
    axes[1].plot(upath[:, 0], upath[:, 1], "o-", color="tab:red", ms=5, lw=0.8, label="u^[k−1], k = 1..")
    axes[1].plot(*uh, "r*", ms=14, label="û")
    axes[1].set_xlabel("u₁")
    axes[1].set_ylabel("u₂")
    axes[1].set_aspect("equal")
    axes[1].legend(fontsize=7)
    axes[1].set_title("dual function g(u) (eq. 10)")
    axes[0].set_title("method of multipliers (eqs. 13-15)")
    ctx.save_figure(fig, "fig3_method_of_multipliers.png")


def _fig4_admm_vs_multipliers(
    ctx: ExperimentContext, a: dict[str, Any], two_node: dict[str, Any], iterations_2d: int
) -> None:
    """Fig. 4: the method of multipliers against ADMM, and the dual values along each run."""
    fig, axes = pyplot().subplots(1, 2, figsize=(11, 5))
    _primal_axes(axes[0], a, two_node, list(STYLES))
    for key, (mk, col, lab) in STYLES.items():
        axes[1].plot(np.arange(iterations_2d + 1), a[key]["dual_value"], mk + "-", color=col, label=lab, lw=0.8)
    axes[1].axhline(a["optimal_value"], color="k", ls="--", lw=0.8, label="Σ f_i(x̂)")
    axes[1].set_xlabel("iteration k (g at u^[k])")
    axes[1].set_ylabel("g(u)")
    axes[1].legend(fontsize=7)
    axes[0].set_title("8 iterations from u⁰ = 0")
    ctx.save_figure(fig, "fig4_admm_vs_multipliers.png")


def _fig5_constraint_nodes(ctx: ExperimentContext, b: dict[str, Any]) -> None:
    """Fig. 5: the graph with both constraint sets, and the convergence of each."""
    g: Graph = b["_graph"]
    pos = g.positions
    assert pos is not None
    fig, axes = pyplot().subplots(1, 3, figsize=(15, 4.5))
    for ax, key, title in ((axes[0], "C_full", "C = {1,3,4,6,9}"), (axes[1], "C_reduced", "C = {1,3,4,9}")):
        C = b["_sets"][key]
        unused = {tuple(e) for e in C.unused_links.tolist()}
        for i, j in g.links.tolist():
            style = ":" if (i, j) in unused else "-"
            ax.plot(pos[[i, j], 0], pos[[i, j], 1], style, color="tab:blue", lw=1.5)
        mask = C.mask
        ax.plot(pos[~mask, 0], pos[~mask, 1], "ko", ms=7)
        ax.plot(pos[mask, 0], pos[mask, 1], "r^", ms=10)
        for k in range(g.n_nodes):
            ax.annotate(g.names[k], pos[k], xytext=(5, 5), textcoords="offset points")
        ax.set_title(title + (f" (dotted: {len(unused)} unused links)" if unused else ""))
        ax.set_aspect("equal")
        ax.axis("off")
    for key, col in (("C_full", "tab:red"), ("C_reduced", "tab:gray"), ("C_all", "tab:blue")):
        curve = b["_curves"][key]
        axes[2].semilogy(
            np.arange(curve.size), curve, color=col, label=f"{key}: {b[key]['iterations_to_1e-6']} it. to 1e-6"
        )
    axes[2].axhline(1e-6, color="k", ls=":", lw=0.8)
    axes[2].set_xlabel("iteration k")
    axes[2].set_ylabel("max_i ‖x_i − x̂‖ / ‖x̂‖")
    axes[2].legend(fontsize=8)
    axes[2].set_title(f"ρ = {b['rho']:g}, first of {b['draws']} random problems")
    ctx.save_figure(fig, "fig5_constraint_nodes.png")


def _fig9_rho(ctx: ExperimentContext, c: dict[str, Any]) -> None:
    """The ρ sweep and Fig. 9-like per-node curves."""
    fig, axes = pyplot().subplots(1, 2, figsize=(12, 4.5))
    for key, mk in (("all", "o-"), ("min_cover", "s-")):
        v = [np.nan if x is None else x for x in c["iterations_to_1e-6"][key]]
        axes[0].semilogx(c["rho"], v, mk, label=f"C = {key}")
    axes[0].set_xlabel("ρ (W = ρI)")
    axes[0].set_ylabel("iterations to max_i ‖x_i − x̂‖/‖x̂‖ ≤ 1e-6")
    axes[0].legend()
    axes[0].set_title(f"{c['n_nodes']}-node random network, p = 6, m_i = 3")
    colours = ["tab:blue", "tab:red", "tab:orange"]
    for (rho, dist), col in zip(c["_curves"].items(), colours, strict=False):
        axes[1].semilogy(np.arange(dist.shape[0]), dist, color=col, lw=0.4, alpha=0.6)
        axes[1].plot([], [], color=col, label=f"ρ = {rho}")
    axes[1].set_xlabel("iteration k")
    axes[1].set_ylabel("‖x_i^[k] − x̂‖ (every node)")
    axes[1].legend()
    ctx.save_figure(fig, "fig9_rho.png")


def _figure_nonlinear(ctx: ExperimentContext, d: dict[str, Any]) -> None:
    """The range problem of §4.3: the nodes and targets, and each variant's distance to Gauss–Newton."""
    plt = pyplot()
    g: Graph = d["_graph"]
    pos = g.positions
    assert pos is not None
    fig, axes = plt.subplots(1, 2, figsize=(11, 4.5))
    for i, j in g.links.tolist():
        axes[0].plot(pos[[i, j], 0], pos[[i, j], 1], "-", color="0.75", lw=0.8)
    axes[0].plot(pos[:, 0], pos[:, 1], "ko", ms=4, label="nodes (range to both targets)")
    tg = np.array(d["targets_m"])
    axes[0].plot(tg[:, 0], tg[:, 1], "r*", ms=14, label="targets (truth)")
    est = d["_nl"].estimates.reshape(-1, 2, 2)
    axes[0].plot(est[:, :, 0].ravel(), est[:, :, 1].ravel(), "b+", ms=8, label="x_i (every node, eq. 23)")
    x0 = np.array(d["x0"]).reshape(2, 2)
    axes[0].plot(x0[:, 0], x0[:, 1], "gx", ms=8, label="start x⁰")
    axes[0].set_aspect("equal")
    axes[0].set_xlabel("x [m]")
    axes[0].set_ylabel("y [m]")
    axes[0].legend(fontsize=7)
    nl = d["_nl"].trace["max_distance_to_reference"]
    axes[1].semilogy(np.arange(nl.size), nl, label="nonlinear x-update (eq. 23)")
    lin = d["_lin"]
    cum = np.cumsum(lin.trace["inner_iterations"])
    axes[1].semilogy(cum, lin.trace["max_distance_to_reference"], "o-", label="linearized (end of each outer step)")
    axes[1].set_xlabel("ADMM iterations")
    axes[1].set_ylabel("max_i ‖x_i − x̂_GN‖ [m]")
    axes[1].legend(fontsize=8)
    axes[1].set_title("against centralized Gauss–Newton")
    ctx.save_figure(fig, "fig_nonlinear_ranges.png")
