"""Figures 7–11 of paper 000 for :mod:`distnav.experiments.codebias` (the station network, the recursive
centralized solutions, ADMM's convergence per ρ and per initial value, the per-node differences)."""

from __future__ import annotations

from typing import Any

import numpy as np

from distnav.experiments.common import ExperimentContext, pyplot
from distnav.models.gnss.codebias import CodeBiasData

COLOURS = ("tab:red", "tab:green", "tab:blue", "tab:orange")


def _curves(ax: Any, values: np.ndarray, colour: str | None) -> tuple[float, float]:
    """One line per node (columns of ``values`` against the iteration) as a single LineCollection (fast).
    Returns the (min, max) of the finite plotted values (positive ones on a log axis) for the caller's limits."""
    from matplotlib.collections import LineCollection

    d = np.asarray(values, dtype=float)
    if ax.get_yscale() == "log":
        d = np.where(d > 0, d, np.nan)
    k = np.arange(d.shape[0], dtype=float)
    segs = np.stack([np.broadcast_to(k[:, None], d.shape), d], axis=-1).transpose(1, 0, 2)
    if colour is None:
        colors: Any = pyplot().get_cmap("tab20")(np.arange(d.shape[1]) % 20)
        ax.add_collection(LineCollection(list(segs), colors=colors, linewidths=0.4))
    else:
        ax.add_collection(LineCollection(list(segs), colors=colour, linewidths=0.4, alpha=0.5))
    ax.set_xlim(0, k[-1])
    finite = d[np.isfinite(d)]
    return (float(finite.min()), float(finite.max())) if finite.size else (1.0, 1.0)


def _set_ylim(ax: Any, bounds: list[tuple[float, float]], log: bool) -> None:
    lo = min(b[0] for b in bounds)
    hi = max(b[1] for b in bounds)
    if log:
        ax.set_ylim(max(lo, 1e-12) / 2, hi * 2)
    else:
        pad = 0.05 * (hi - lo) + 1e-12
        ax.set_ylim(lo - pad, hi + pad)


def figures(ctx: ExperimentContext, s: Any, r: Any, threshold_m: float) -> None:
    """Figs. 7–11 of paper 000 from :func:`distnav.experiments.codebias.run`'s ``Sessions`` and ``AdmmRuns``
    (this module sits below it: it takes them as they are), with the convergence threshold drawn in Figs. 9–10."""
    _fig7_network(ctx, s.net, s.constraint_nodes.nodes)
    _fig8_centralized(ctx, s.data, s.x_rec, s.s_rec, (r.best, r.worst))
    _fig9_rho(ctx, r.by_rho, threshold_m)
    _fig10_init(ctx, r.by_init, threshold_m)
    _fig11_per_node(ctx, s.data, r.tracks, s.x_hat, s.solution.sigma_m, (r.best, r.worst))


def _fig7_network(ctx: ExperimentContext, net: Any, cnodes: np.ndarray) -> None:
    """Fig. 7: the station network (``StationNetwork``) and its constraint nodes."""
    plt = pyplot()
    g = net.graph
    fig, ax = plt.subplots(figsize=(10, 5))
    for i, j in g.links:
        lo = net.lon_deg[[i, j]]
        if abs(lo[0] - lo[1]) > 180:
            continue
        ax.plot(lo, net.lat_deg[[i, j]], "-", color="tab:blue", lw=0.7)
    ax.plot(net.lon_deg, net.lat_deg, "k.", ms=4)
    ax.plot(net.lon_deg[cnodes], net.lat_deg[cnodes], "r^", ms=8, label=f"{cnodes.size} constraint nodes")
    ax.set_xlim(-180, 180)
    ax.set_ylim(-90, 90)
    ax.set_xlabel("longitude [°]")
    ax.set_ylabel("latitude [°]")
    ax.set_title(f"{g.n_nodes} stations, {g.n_links} links")
    ax.legend(loc="lower left")
    ctx.save_figure(fig, "fig7_network.png")


def _fig8_centralized(
    ctx: ExperimentContext, data: CodeBiasData, x_rec: np.ndarray, s_rec: np.ndarray, sats: tuple[int, int]
) -> None:
    """Fig. 8: recursive centralized solutions of the best and the least observed satellite."""
    hours = (np.asarray(data.t_gps_s) - data.t_gps_s[0]) / 3600.0
    fig, axes = pyplot().subplots(1, 2, figsize=(11, 4))
    for ax, k, what in zip(axes, sats, ("best observed", "least observed"), strict=True):
        ax.plot(hours, x_rec[:, k], "k-", lw=1, label="x̂(t)")
        ax.plot(hours, x_rec[:, k] + 3 * s_rec[:, k], "k--", lw=0.8, label="±3σ")
        ax.plot(hours, x_rec[:, k] - 3 * s_rec[:, k], "k--", lw=0.8)
        if data.truth_m is not None:
            ax.axhline(data.truth_m[k], color="tab:green", lw=0.8, label="truth")
        ax.set_title(f"{data.svs[k]} ({what})")
        ax.set_xlabel("time [h]")
        ax.set_ylabel("code bias [m]")
        ax.legend(fontsize=7)
    ctx.save_figure(fig, "fig8_centralized.png")


def _fig9_rho(ctx: ExperimentContext, runs: dict[str, Any], threshold_m: float) -> None:
    """Fig. 9: convergence for each ρ, every node and the worst."""
    fig, axes = pyplot().subplots(1, 2, figsize=(12, 4.5))
    axes[0].set_yscale("log")
    bounds = []
    for (rho, res), c in zip(runs.items(), COLOURS, strict=True):
        bounds.append(_curves(axes[0], res.trace["distance_to_reference"], c))
        axes[0].plot([], [], color=c, label=f"ρ = {rho}")
        axes[1].semilogy(res.trace["max_distance_to_reference"], color=c, label=f"ρ = {rho}")
    _set_ylim(axes[0], bounds, log=True)
    for ax in axes:
        ax.axhline(threshold_m, color="k", ls=":", lw=0.8)
        ax.set_xlabel("iteration k")
        ax.legend(fontsize=8)
        ax.grid(alpha=0.3)
    axes[0].set_ylabel("‖x_i^[k] − x̂‖ [m], 110 nodes")
    axes[1].set_ylabel("max_i ‖x_i^[k] − x̂‖ [m]")
    ctx.save_figure(fig, "fig9_rho.png")


def _fig10_init(ctx: ExperimentContext, init_runs: dict[str, Any], threshold_m: float) -> None:
    """Fig. 10: convergence at ρ = 0.5 from each initial value."""
    fig, ax = pyplot().subplots(figsize=(7, 4.5))
    ax.set_yscale("log")
    bounds = []
    for (label, res), c in zip(init_runs.items(), COLOURS, strict=True):
        bounds.append(_curves(ax, res.trace["distance_to_reference"], c))
        ax.plot([], [], color=c, label=f"x⁰ = {label}")
    _set_ylim(ax, bounds, log=True)
    ax.axhline(threshold_m, color="k", ls=":", lw=0.8)
    ax.set_xlabel("iteration k")
    ax.set_ylabel("‖x_i^[k] − x̂‖ [m]  (ρ = 0.5)")
    ax.legend(fontsize=8)
    ax.grid(alpha=0.3)
    ctx.save_figure(fig, "fig10_init.png")


def _fig11_per_node(
    ctx: ExperimentContext,
    data: CodeBiasData,
    tracks: np.ndarray,
    x_hat: np.ndarray,
    sigma: np.ndarray,
    sats: tuple[int, int],
) -> None:
    """Fig. 11: per-node differences from x̂ (x⁰ = prev.) of the two satellites, with x̂'s 3σ band."""
    fig, axes = pyplot().subplots(1, 2, figsize=(11, 4), sharey=True)
    for col, (ax, k) in enumerate(zip(axes, sats, strict=True)):
        b = _curves(ax, tracks[:, :, col] - x_hat[k], None)
        _set_ylim(ax, [b, (-3 * sigma[k], 3 * sigma[k])], log=False)
        ax.axhline(3 * sigma[k], color="k", ls="--", lw=0.8)
        ax.axhline(-3 * sigma[k], color="k", ls="--", lw=0.8)
        ax.set_title(f"{data.svs[k]}: x_i^[k] − x̂ (ρ = 0.5, x⁰ = prev.)")
        ax.set_xlim(0, min(tracks.shape[0] - 1, 300))
        ax.set_xlabel("iteration k")
    axes[0].set_ylabel("[m]")
    ctx.save_figure(fig, "fig11_per_node.png")
