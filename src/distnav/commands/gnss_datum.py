"""``--datum-satellites`` of ``distnav gnss ionosphere``: the zero-mean datum over a fixed satellite set, held in a
reference product's datum when the set comes from a product (:mod:`distnav.models.gnss.datum`).

``--datum-satellites G01,G02,...`` fixes the set; ``--datum-satellites PRODUCT.BIA`` takes the product's
satellites that have the estimated code pair and holds a missing member at the product's value (the estimates
come out in the product's datum). The datum and the satellites it runs over are printed and written to
``summary.json`` and the Bias-SINEX comments.
"""

from __future__ import annotations

import argparse
import re
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

from distnav.errors import DataFileError, ModelError

__all__ = ["DatumChoice", "check_datum_option", "check_datum_tracked", "datum_choice"]

_PRN = re.compile(r"^G(0[1-9]|[12][0-9]|3[0-2])$")
_ALL_GPS = tuple(f"G{k:02d}" for k in range(1, 33))


@dataclass(frozen=True)
class DatumChoice:
    """The datum's fixed set (``None``: the satellites estimated) and the reference product holding it."""

    members: tuple[str, ...] | None = None
    reference_ns: dict[str, float] | None = None
    reference_name: str | None = None


def _is_list(value: str) -> bool:
    return "," in value or bool(_PRN.match(value.upper()))


def check_datum_option(args: argparse.Namespace) -> None:
    """``--datum-satellites`` before any work: a list of GPS PRNs or an existing product file; zero-mean datum."""
    value = getattr(args, "datum_satellites", None)
    if value is None:
        return
    if args.datum != "zero-mean":
        raise ModelError(f"--datum-satellites fixes the set of the zero-mean datum; the datum is {args.datum}")
    if _is_list(value):
        bad = [s for s in value.split(",") if not _PRN.match(s.strip().upper())]
        if bad:
            raise ModelError(f"--datum-satellites: {' '.join(bad)} not GPS satellites (G01 … G32)")
        if len({s.strip().upper() for s in value.split(",")}) < 2:
            raise ModelError("--datum-satellites needs at least two satellites")
    elif not Path(value).exists():
        raise DataFileError(f"--datum-satellites {value}: neither a list of satellites (G01,G02,…) nor a file")


def datum_choice(args: argparse.Namespace, l1: str, l2: str) -> DatumChoice:
    """The fixed set and, from a product file, its ``l1 − l2`` satellite DSBs [ns]."""
    value = getattr(args, "datum_satellites", None)
    if value is None:
        return DatumChoice()
    if _is_list(value):
        return DatumChoice(tuple(sorted({s.strip().upper() for s in value.split(",")})))
    from distnav.formats.gnss.product_files import product_dsbs

    (prod,) = product_dsbs([value], _ALL_GPS, [], l1, l2)
    if len(prod.satellite) < 2:
        raise DataFileError(f"--datum-satellites {value}: no {l1}-{l2} satellite DSBs in the product")
    return DatumChoice(tuple(sorted(prod.satellite)), dict(prod.satellite), prod.name)


def check_datum_tracked(fixed: DatumChoice, svs: Sequence[str]) -> None:
    """A ``--datum-satellites`` list of which no satellite is tracked: its zero mean runs over no satellite and every
    DSB of the output is undefined (before: written as empty cells, exit 0). A product's set is exempt: its missing
    satellites are held at the product's values."""
    if fixed.members is None or fixed.reference_name is not None:
        return
    if not set(fixed.members) & set(svs):
        raise ModelError(
            f"--datum-satellites {','.join(fixed.members)}: none of them is tracked above the mask by any station "
            f"(tracked: {' '.join(svs)}), so the zero mean would run over no satellite"
        )
