"""Bias-SINEX output of ``distnav gnss ionosphere``: one day's central-filter DSBs and the combination of several
days, satellites on the network's code pair and every receiver on its own (a C1C receiver corrected to C1W keeps
C1C−C2W)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

__all__ = ["write_sinex", "write_combined_sinex"]


def write_combined_sinex(
    path: Path, result: dict[str, Any], summaries: dict[str, Any], svns: dict[str, str] | None = None
) -> None:
    """The combined solution of several days (``multiday.json``) as Bias-SINEX 1.00, receivers on their own codes."""
    from distnav.formats.gnss.bias_sinex import BiasSinexHeader, write_bias_sinex
    from distnav.output import atomic_write_text

    first = summaries[min(summaries)]
    codes = list(first["codes"].values())
    comb, sd = result["combined_ns"], result["combined_std_ns"]
    text = write_bias_sinex(
        None,
        obs1=codes[0],
        obs2=codes[1],
        start=f"{min(summaries)}T00:00:00",
        end=np.datetime64(max(summaries)) + np.timedelta64(1, "D"),
        satellites={k: (v, sd[k]) for k, v in comb.items() if not k.startswith("rx:")},
        stations={k[3:]: (v, sd[k]) for k, v in comb.items() if k.startswith("rx:")},
        station_codes={k: tuple(v) for s in summaries.values() for k, v in (s.get("station_codes") or {}).items()},
        header=BiasSinexHeader(
            comments=[
                f"distnav gnss ionosphere, {len(summaries)} days combined: {', '.join(summaries)}",
                "datum: zero-mean satellite datum over the satellites common to the days; each day's: "
                + "; ".join(
                    f"{d}: {s.get('datum_statement', s.get('datum', ''))}" for d, s in sorted(summaries.items())
                ),
                f"sigma: rho x mean daily variance + (1 - rho) x that of independent days, rho = "
                f"{result.get('repeating_share', 0.0):.2f} the share of the daily variance that repeats (from the "
                "repeatability; averaging days does not reduce it)",
            ]
        ),
        svns=svns,
    )
    atomic_write_text(path, str(text))


def write_sinex(
    path: Path,
    data: Any,
    final: tuple[dict[str, float], dict[str, float]],
    l1: str,
    l2: str,
    datum: str,
    times: list[str],
    *,
    datum_text: str = "",
    svns: dict[str, str] | None = None,
) -> Path:
    """The central filter's final DSBs as Bias-SINEX 1.00 (satellites and receivers with σ); ``datum_text``: the
    datum and its satellites in words (a comment); ``svns``: PRN → SVN from a reference product."""
    from distnav.formats.gnss.bias_sinex import BiasSinexHeader, write_bias_sinex

    val, sd = final
    step = float(np.median(np.diff(data.t_gps_s))) if data.t_gps_s.size > 1 else 30.0
    end = np.datetime64(times[-1], "s") + np.timedelta64(int(round(step)), "s")
    from distnav.output import atomic_write_text

    text = write_bias_sinex(
        None,
        obs1=l1,
        obs2=l2,
        start=times[0],
        end=end,
        satellites={k: (v, sd[k]) for k, v in val.items() if not k.startswith("rx:")},
        stations={k[3:]: (v, sd[k]) for k, v in val.items() if k.startswith("rx:")},
        station_codes={s: (c.get(1, l1), c.get(data.band, l2)) for s, c in data.codes.items()},
        svns=svns,
        header=BiasSinexHeader(
            sampling_s=step,
            datum="zero-mean satellite datum" if datum == "zero-mean" else f"{datum} datum",
            comments=[
                f"distnav gnss ionosphere, central filter, datum {datum} "
                f"({'IGS convention' if datum == 'zero-mean' else 'not the IGS convention'}): {datum_text}",
                f"stations: {' '.join(data.stations)}; geometry-free {l1}-{l2} code, "
                f"{'carrier-levelled' if data.levelled else 'raw'}",
                "sigma: formal x sqrt(variance factor x (1+rho)/(1-rho)) of the predicted residuals",
            ],
        ),
    )
    atomic_write_text(path, str(text))
    return path
