"""Figures of :mod:`distnav.experiments.ckf_ionosphere` (paper 003 Figs. 8, 10–13 and the CKF on simulated data),
one function each, from :class:`IonosphereFigures` (what the run computed, and the scenario's layout)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from distnav.algorithms.kalman import FilterSeries
from distnav.experiments.common import ExperimentContext, pyplot
from distnav.models.gnss.ionosphere import GF_M_PER_DSB_NS, TECU_L1_M, IonosphereGeometry, IonosphereStateLayout
from distnav.network.graph import Graph

LABELS = ["ν_o [m]", "ν_φ [m/rad]", "ν_ψ [m/rad]"]


@dataclass(frozen=True)
class IonosphereFigures:
    """What the figures show: the network and its receivers' (east, north) layout [km], the geometry and state
    layout, the central and local filters, the CKF/central and local/central std ratios, the DCB times to 0.5 ns
    (central, CKF per k_n), the CKF on simulated data with the truth, the first steady epoch, the epoch interval
    [s] and the elevation mask [°]."""

    graph: Graph
    east_north_km: np.ndarray
    geometry: IonosphereGeometry
    layout: IonosphereStateLayout
    central: FilterSeries
    local: FilterSeries
    ckf_ratio: dict[int, np.ndarray]
    local_ratio: np.ndarray
    t_central: np.ndarray
    t_ckf: dict[int, np.ndarray]
    data_series: FilterSeries
    truth: np.ndarray
    steady: int
    interval_s: float
    mask_deg: float

    @property
    def hours(self) -> np.ndarray:
        """Perth local time of every epoch [h]."""
        return 8.0 + np.arange(self.central.std.shape[0]) * self.interval_s / 3600.0

    @property
    def steady_slice(self) -> slice:
        T = self.central.std.shape[0]
        return slice(min(self.steady, T - 1), T)


def figures(ctx: ExperimentContext, f: IonosphereFigures) -> None:
    """Every figure of the reproduction."""
    _fig08_10_network_visibility(ctx, f)
    _fig11_central_vs_local(ctx, f)
    _fig12_ckf_to_central(ctx, f)
    _fig13_dcb_time_boxplots(ctx, f)
    _ckf_truth(ctx, f)


def _fig08_10_network_visibility(ctx: ExperimentContext, f: IonosphereFigures) -> None:
    """Figs. 8 and 10: the network and the satellites' visibility."""
    plt = pyplot()
    T, hours, n, graph, layout = f.central.std.shape[0], f.hours, f.graph.n_nodes, f.graph, f.layout
    geo, pos = f.geometry, f.east_north_km
    fig, axes = plt.subplots(1, 2, figsize=(12, 4.5))
    for i, j in graph.links:
        axes[0].plot(pos[[i, j], 0], pos[[i, j], 1], "r-", lw=1)
    axes[0].plot(pos[:, 0], pos[:, 1], "o", mfc="w", mec="k", ms=14)
    for i in range(n):
        axes[0].text(pos[i, 0], pos[i, 1], str(i + 1), ha="center", va="center", fontsize=8)
    axes[0].set_aspect("equal")
    axes[0].set_xlabel("east [km]")
    axes[0].set_ylabel("north [km]")
    axes[0].set_title("Perth network (links ≤ 4 km)")
    vis = np.asarray(geo.tracked.any(axis=1))
    for k in range(len(layout.svs)):
        tt = np.where(vis[:, k], hours, np.nan)
        axes[1].plot(tt, np.full(T, k), lw=4)
    axes[1].set_yticks(range(len(layout.svs)))
    axes[1].set_yticklabels([s[1:] for s in layout.svs], fontsize=6)
    axes[1].set_xlabel("Perth local time [h]")
    axes[1].set_ylabel("PRN")
    axes[1].set_title(f"visibility above {f.mask_deg:.0f}° (synthetic constellation)")
    ctx.save_figure(fig, "fig08_10_network_visibility.png")


def _fig11_central_vs_local(ctx: ExperimentContext, f: IonosphereFigures) -> None:
    """Fig. 11: central against single-receiver standard deviations, from 1 h on."""
    plt = pyplot()
    hours, central, local, local_ratio, labels = f.hours, f.central, f.local, f.local_ratio, LABELS
    sl = f.steady_slice
    fig, axes = plt.subplots(3, 2, figsize=(12, 8), sharex=True)
    for k in range(3):
        axes[k, 0].plot(hours[sl], central.std[sl, 0, k], "g", label="central")
        axes[k, 0].plot(hours[sl], local.std[sl, 0, k], "r", label="local (receiver 1)")
        axes[k, 0].set_ylabel(f"std {labels[k]}")
        axes[k, 1].plot(hours[sl], local_ratio[sl, 0, k], "k")
        axes[k, 1].set_ylabel("local / central")
        axes[k, 0].grid(alpha=0.3)
        axes[k, 1].grid(alpha=0.3)
    axes[0, 0].legend()
    axes[2, 0].set_xlabel("Perth local time [h]")
    axes[2, 1].set_xlabel("Perth local time [h]")
    fig.suptitle("Fig. 11: central vs single-receiver standard deviations, from 1 h after the start")
    ctx.save_figure(fig, "fig11_central_vs_local.png")


def _fig12_ckf_to_central(ctx: ExperimentContext, f: IonosphereFigures) -> None:
    """Fig. 12: CKF-to-central std ratios of every receiver, for k_n = 4 and 12."""
    plt = pyplot()
    hours, ckf_ratio, n, labels, sl = f.hours, f.ckf_ratio, f.graph.n_nodes, LABELS, f.steady_slice
    interval_s = f.interval_s
    kshow = [k for k in ckf_ratio if k in (4, 12)] or list(ckf_ratio)[:2]
    fig, axes = plt.subplots(3, len(kshow), figsize=(6 * len(kshow), 8), sharex=True, squeeze=False)
    cmap = plt.get_cmap("tab20")
    for c, kn in enumerate(kshow):
        for k in range(3):
            for i in range(n):
                axes[k, c].plot(
                    hours[sl], ckf_ratio[kn][sl, i, k], color=cmap(i), lw=0.9, label=f"rx {i + 1}" if k == 0 else None
                )
            axes[k, c].set_ylabel(f"CKF/central {labels[k].split()[0]}")
            axes[k, c].grid(alpha=0.3)
        axes[0, c].set_title(f"k_n = {kn} (δ = {interval_s / kn:.0f} s)")
        axes[2, c].set_xlabel("Perth local time [h]")
    axes[0, -1].legend(fontsize=6, ncol=2)
    ctx.save_figure(fig, "fig12_ckf_to_central.png")


def _fig13_dcb_time_boxplots(ctx: ExperimentContext, f: IonosphereFigures) -> None:
    """Fig. 13: minutes to a DCB std of 0.5 ns, central and per receiver, per k_n."""
    plt = pyplot()
    t_ckf, t_central, n, interval_s = f.t_ckf, f.t_central, f.graph.n_nodes, f.interval_s
    fig, axes = plt.subplots(len(t_ckf), 1, figsize=(11, 3.2 * len(t_ckf)), squeeze=False)
    for r, (kn, tt) in enumerate(t_ckf.items()):
        data = [t_central[np.isfinite(t_central)]] + [tt[i][np.isfinite(tt[i])] for i in range(n)]
        axes[r, 0].boxplot(data, whis=(0, 100), tick_labels=["Cen."] + [str(i + 1) for i in range(n)])
        axes[r, 0].set_ylabel("minutes to std < 0.5 ns")
        axes[r, 0].set_title(f"δ = {interval_s / kn:.0f} s (k_n = {kn})")
        axes[r, 0].grid(alpha=0.3)
    fig.tight_layout()
    ctx.save_figure(fig, "fig13_dcb_time_boxplots.png")


def _ckf_truth(ctx: ExperimentContext, f: IonosphereFigures) -> None:
    """The CKF on simulated data against the truth: receiver 1's ν_o error and every DCB's at the end."""
    plt = pyplot()
    hours, ds, truth, layout, n = f.hours, f.data_series, f.truth, f.layout, f.graph.n_nodes
    fig, axes = plt.subplots(2, 1, figsize=(11, 6))
    err = ds.estimates[:, 0, 0] - truth[:, 0]
    sd = ds.std[:, 0, 0]
    axes[0].plot(hours, err / TECU_L1_M, "b", lw=0.8, label="estimate − truth, receiver 1")
    axes[0].fill_between(hours, -3 * sd / TECU_L1_M, 3 * sd / TECU_L1_M, color="0.8", label="±3σ (Fig. 7)")
    axes[0].set_ylim(-3 * np.nanmedian(sd) / TECU_L1_M * 4, 3 * np.nanmedian(sd) / TECU_L1_M * 4)
    axes[0].set_ylabel("ν_o error [TECU]")
    axes[0].legend(fontsize=8)
    axes[0].grid(alpha=0.3)
    p0 = layout.n_tec
    e_dcb = (ds.estimates[-1, :, p0:] - truth[-1, p0:]) / GF_M_PER_DSB_NS
    s_dcb = ds.std[-1, :, p0:] / GF_M_PER_DSB_NS
    xs = np.arange(e_dcb.shape[1])
    for i in range(n):
        axes[1].plot(xs + 0.03 * (i - n / 2), -e_dcb[i], ".", ms=3)
    axes[1].errorbar(
        xs,
        np.zeros_like(xs, dtype=float),
        yerr=3 * np.nanmax(s_dcb, axis=0),
        fmt="none",
        ecolor="k",
        capsize=2,
        label="±3σ (largest over receivers)",
    )
    axes[1].set_xticks(xs)
    axes[1].set_xticklabels([s[1:] for s in layout.dcb_svs], fontsize=6)
    axes[1].set_ylabel("DCB error at the end [ns]")
    axes[1].legend(fontsize=8)
    axes[1].grid(alpha=0.3)
    ctx.save_figure(fig, "ckf_truth.png")
