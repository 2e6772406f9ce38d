"""The CSV files of a simulated hall (:class:`~distnav.models.uwb.hall.HallNetwork`), as texts by file stem.

``ranges`` (``a,b,range_m``, every sample in the direction it was logged), ``known`` and ``truth``
(``id,x_m,y_m,z_m``), ``heights`` (``id,z_m``: the surveyed heights) — what ``distnav uwb solve`` reads (its readers:
:mod:`distnav.formats.uwb.io`) — plus the labels a user never has: ``links_truth`` (``a,b,distance_m,nlos,bias_m``)
and ``delays`` (``id,offset_m``). The writing is the caller's (:func:`distnav.experiments.uwb_field.write_hall`).
"""

from __future__ import annotations

from collections.abc import Iterable
from typing import Any

from distnav.models.uwb.hall import HallNetwork

__all__ = ["HALL_FILES", "hall_csv_texts"]

HALL_FILES = ("ranges", "known", "truth", "heights", "links_truth", "delays")


def hall_csv_texts(net: HallNetwork) -> dict[str, str]:
    """``{stem: text}`` of every file of :data:`HALL_FILES` for ``net`` (0.1 mm resolution)."""
    a, b = net.sample_pairs()
    t = net.truth_m

    def text(lines: list[str]) -> str:
        return "\n".join(lines) + "\n"

    def table(rows: Iterable[Any]) -> str:
        return text(["id,x_m,y_m,z_m"] + [f"{net.ids[k]},{t[k, 0]:.4f},{t[k, 1]:.4f},{t[k, 2]:.4f}" for k in rows])

    return {
        "ranges": text(["a,b,range_m"] + [f"{x},{y},{r:.4f}" for x, y, r in zip(a, b, net.range_m, strict=True)]),
        "known": table(net.known),
        "truth": table(range(net.n_anchors)),
        "heights": text(["id,z_m"] + [f"{k},{z:.4f}" for k, z in zip(net.ids, net.surveyed_z_m, strict=True)]),
        "links_truth": text(
            ["a,b,distance_m,nlos,bias_m"]
            + [
                f"{net.ids[i]},{net.ids[j]},{d:.4f},{int(f)},{bm:.4f}"
                for (i, j), d, f, bm in zip(net.links, net.distance_m, net.nlos, net.bias_m, strict=True)
            ]
        ),
        "delays": text(["id,offset_m"] + [f"{k},{o:.4f}" for k, o in zip(net.ids, net.offset_m, strict=True)]),
    }
