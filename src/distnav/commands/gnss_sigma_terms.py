"""The σ terms of ``distnav gnss ionosphere`` that another part of the same data supplies (issue 32, gnss8;
:mod:`distnav.models.gnss.sigmaterms`): the arcs' variance factor of the receivers' GPS arcs where the system's
own is not estimable, and the GLONASS receivers' FDMA channel biases. Each choice is printed as a ``model choice``
note and written to ``summary.json`` (``sigma_terms``)."""

from __future__ import annotations

import argparse
import re
from dataclasses import replace
from typing import Any

import numpy as np

from distnav.errors import DataFileError, ModelError

__all__ = ["GLONASS_IFB_PRIOR_NS", "borrowed_arc_factor", "glonass_channel_ifb", "sigma_terms"]

GLONASS_IFB_PRIOR_NS = 2.0
"""Default σ [ns] of one receiver's C/A-pair (C1C−C2C) FDMA channel bias where it cannot be estimated (one
receiver). GLONASS code inter-frequency biases reach several metres per code and depend on the receiver's make and
firmware (Tsujii et al. 2000; Shi et al. 2013, GPS Solutions 17:439–451; as reviewed in GPS Solutions 2017,
doi:10.1007/s10291-017-0618-5); 2 ns of the DSB is a round value at the low end of that, not derived from those
papers (docs/gnss.md says what it was checked on). No prior is applied to the P pair (C1P−C2P) unless given."""


def sigma_terms(
    args: argparse.Namespace, data: Any, orbit: Any, options: Any, series: list[Any]
) -> tuple[Any, list[Any]]:
    """The data with the terms' notes and ``sigma_terms`` record, and the series with the terms applied;
    ``orbit`` the run's orbits, ``options`` its :class:`~distnav.commands.gnss_ionosphere_data.NetworkOptions`."""
    record: dict[str, Any] = {}
    notes: list[str] = []
    system = getattr(args, "system", "G")
    central = next((s for s in series if s.label == "central"), None)
    if system != "G" and args.levelling == "arc" and central is not None and central.arc_variance_factor is None:
        series, note, rec = borrowed_arc_factor(args, options, series)
        notes += [note] if note else []  # without: sigma_limits says the factor is missing
        record["arc_factor"] = rec
    if system == "R" and data.frequencies_hz is not None:
        series, ifb = glonass_channel_ifb(args, data, orbit, options, series)
        if ifb is not None:
            notes.append(ifb.statement())
            record["glonass_channel_ifb"] = ifb.as_dict()
    return replace(data, notes=[*data.notes, *notes], sigma_terms=record), series


def borrowed_arc_factor(
    args: argparse.Namespace, network: Any, series: list[Any]
) -> tuple[list[Any], str | None, dict[str, Any]]:
    """The central filter of the same observation files' GPS C1C−C2W arcs (same stations, window, grid and model)
    and its arcs' variance factor, given to the series without one."""
    from distnav.commands.gnss_ionosphere_data import network_data
    from distnav.formats.gnss.rinex import read_navigation, read_sp3
    from distnav.models.gnss.gfnetwork import BiasFilterOptions, run_bias_filters
    from distnav.models.gnss.sigmaterms import with_arc_factor

    rec: dict[str, Any] = {"source": "GPS C1C-C2W arcs of the same files", "factor": None}
    try:
        orbit: Any = (
            read_navigation(args.nav[0], max_age_s=args.nav_max_age * 3600.0, systems=("G",))
            if args.nav
            else read_sp3(args.sp3, system="G")
        )
        stations = tuple(e for e in (args.exclude or []) if re.match(r"^[A-Za-z0-9]{4}$", e))
        options = replace(network, l2_code="C2W", exclude=stations)
        gps = network_data(args.obs, orbit, options, l1_code="C1C", tlim=tuple(args.tlim) if args.tlim else None)
        (central,), _ = run_bias_filters(gps, BiasFilterOptions(local=False, between_station_level=None))
    except (DataFileError, ModelError) as exc:
        rec["not_borrowed"] = f"no GPS C1C/C2W arcs: {exc}"
        return series, None, rec
    factor = central.arc_variance_factor
    if factor is None:
        rec["not_borrowed"] = "the GPS arcs' factor is not estimable either"
        return series, None, rec
    rec["factor"] = float(factor)
    note = (
        f"model choice: the arcs' variance factor is not estimable (fewer than 8 degrees of freedom beyond the "
        f"biases), so the realistic σ takes the factor of the same receivers' GPS C1C-C2W arcs, σ̂²_arc "
        f"{factor:.2f} (formal × {np.sqrt(factor):.2f}; its arcs assumed to err as GPS's: docs/gnss.md)"
    )
    return with_arc_factor(series, float(factor)), note, rec


def glonass_channel_ifb(
    args: argparse.Namespace, data: Any, orbit: Any, network: Any, series: list[Any]
) -> tuple[list[Any], Any]:
    """The receivers' channel-bias consider term. Its σ: ``--glonass-ifb-sigma-ns`` when given; else from the
    data — the single-station solutions of two or more receivers, or for one receiver on a C/A pair the same
    receiver's P pair (C1P−C2P) of the same files; else for a C/A pair the prior :data:`GLONASS_IFB_PRIOR_NS`
    (a P pair alone gets none)."""
    from distnav.models.gnss.sigmaterms import (
        ChannelIfb,
        channel_ifb_variance_ns2,
        channels_from_f1_hz,
        with_channel_ifb,
    )

    n = len(data.stations)
    k = channels_from_f1_hz(data.frequencies_hz[0])
    by_sv = dict(zip(data.layout.svs, k.tolist(), strict=True))
    given = getattr(args, "glonass_ifb_sigma_ns", None)
    ca = "C" in (args.l1_code.upper()[-1:], args.l2_code.upper()[-1:])
    ifb = None
    if given is not None:
        ifb = ChannelIfb(float(given), "given", n, mode="added" if n == 1 else "floor")
    elif n >= 2:
        ifb = _between_receivers(data, series, by_sv)
    elif ca:
        ifb = _against_the_p_pair(args, data, orbit, network, series, by_sv)
    if ifb is None and given is None and ca:
        ifb = ChannelIfb(GLONASS_IFB_PRIOR_NS, "prior", n, mode="added" if n == 1 else "floor")
    if ifb is None:
        return series, None
    floor = ifb.mode == "floor"
    of_mean_ns2 = channel_ifb_variance_ns2(k, ifb.sigma_ns, n)  # the receivers' mean per channel
    of_own_ns2 = channel_ifb_variance_ns2(k, ifb.sigma_ns, 1)  # a single-station filter carries its receiver's own
    out = [
        with_channel_ifb([s], n, of_own_ns2 if s.label.startswith("local:") else of_mean_ns2, floor=floor)[0]
        for s in series
    ]
    return out, ifb


def _between_receivers(data: Any, series: list[Any], by_sv: dict[str, float]) -> Any:
    """σ_ifb from every pair of receivers' single-station satellite DSBs (each pair's channel means: 2σ_ifb²)."""
    from distnav.models.gnss.sigmaterms import ChannelIfb, channel_ifb_sigma_ns

    n = len(data.stations)
    local = [s for s in series if s.label.startswith("local:")]
    est, K, dof = [], 0, 0
    for a in range(len(local)):
        for b in range(a + 1, len(local)):
            d = local[a].dsb_ns[-1, n:] - local[b].dsb_ns[-1, n:]
            sig, K_ab, dof_ab = channel_ifb_sigma_ns(dict(zip(data.layout.svs, d.tolist(), strict=True)), by_sv)
            if np.isfinite(sig):
                est.append(sig**2 / 2.0)  # two independent receivers: 2σ_ifb²
                K, dof = max(K, K_ab), max(dof, dof_ab)
    return ChannelIfb(float(np.sqrt(np.mean(est))), "between receivers", n, K, dof, "floor") if est else None


def _against_the_p_pair(
    args: argparse.Namespace, data: Any, orbit: Any, network: Any, series: list[Any], by_sv: dict[str, float]
) -> Any:
    """One receiver on a C/A pair: the central filter of its P pair (C1P−C2P) in the same files and window; the
    channel means of the C/A minus P satellite DSBs carry the difference of the two pairs' channel patterns
    (σ_CA² + σ_P² if independent: an upper bound of the C/A pair's; nothing of a pattern both pairs share, as
    DGAR's). ``None`` where the P codes are not tracked."""
    from distnav.commands.gnss_ionosphere_data import network_data
    from distnav.models.gnss.gfnetwork import BiasFilterOptions, run_bias_filters
    from distnav.models.gnss.sigmaterms import ChannelIfb, channel_ifb_sigma_ns

    try:
        p = network_data(
            args.obs,
            orbit,
            replace(network, l2_code="C2P"),
            l1_code="C1P",
            tlim=tuple(args.tlim) if args.tlim else None,
            system="R",
        )
        (cp,), _ = run_bias_filters(p, BiasFilterOptions(local=False, between_station_level=None))
    except (DataFileError, ModelError):
        return None
    central = next(s for s in series if s.label == "central")
    ours = dict(zip(data.layout.svs, central.dsb_ns[-1, 1:].tolist(), strict=True))
    theirs = dict(zip(p.layout.svs, cp.dsb_ns[-1, len(p.stations) :].tolist(), strict=True))
    d = {sv: ours[sv] - theirs[sv] for sv in ours if sv in theirs}
    sig, K, dof = channel_ifb_sigma_ns(d, by_sv)
    return ChannelIfb(float(sig), "P pair of the same receiver", 1, K, dof) if np.isfinite(sig) else None
