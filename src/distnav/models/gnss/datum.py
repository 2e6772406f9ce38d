"""The datum of the DSB product: which satellites it runs over, and a fixed set that a missing satellite cannot move.

The zero-mean datum (:func:`~distnav.models.gnss.gfbias.datum_transform`, the IGS convention) makes the mean of
the satellite DSBs zero. Over *the satellites estimable at the epoch* (the default) it moves every DSB when a
satellite is missing: the mean then runs over 15–19 satellites in a 6-h session and shifts everything by
``(b^k − mean)/(S − 1)`` per missing satellite ``k`` (0.2–0.7 ns measured in 6-h sessions, issue 32).

A **fixed set** ``F`` (``--datum-satellites``) defines the datum by its members only. With the DSBs ``r^s`` of a
reference product for the members (its satellite list: ``--datum-satellites PRODUCT.BIA``), a member missing from
the data is replaced by the product's value: the condition is

    ``Σ_{s ∈ F ∩ present} (b̃^s − r^s) = 0``,   i.e.  ``b̃^s = b^s − mean_{F∩present}(b) + mean_{F∩present}(r)``

(receivers the other way), so the estimates come out in the product's datum and a missing member moves the others
only by ``(d^k − mean d)/(|F ∩ present| − 1)`` with ``d = b − r`` the estimate's error against the product (a
few hundredths of a ns), not by ``b^k``'s distance from the mean. Without a product, missing members leave the
mean over the present members (the datum then differs from the full set's, and :func:`datum_statement` says so).
The product's values enter as constants: the stated σ are those of the zero-mean-over-``F ∩ present`` estimates
(the product's own error is not propagated).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import numpy as np

from distnav.errors import ModelError
from distnav.models.gnss.gfbias import BiasStateLayout

__all__ = ["present_satellites", "datum_offset_ns", "datum_statement"]


def present_satellites(layout: BiasStateLayout, estimable: np.ndarray) -> np.ndarray:
    """(S,) bool: the satellites whose bias is estimable in the state's estimable pattern ``estimable`` (p,)."""
    scol = layout.satellite_column()
    est = np.asarray(estimable, bool)
    return np.where(scol >= 0, est[np.maximum(scol, 0)], True)


def datum_offset_ns(
    layout: BiasStateLayout,
    estimable: np.ndarray,
    members: Sequence[str],
    fill_ns: Mapping[str, float],
) -> np.ndarray:
    """(n + S,) constant [ns] added to the zero-mean-over-``F ∩ present`` DSBs (receivers then satellites) to put
    them in the datum of the reference product ``fill_ns``: ``+mean_{F∩present}(r)`` on the satellites, ``−`` on
    the receivers (module docstring). Every member needs a value in ``fill_ns``."""
    lacking = [s for s in members if s not in fill_ns]
    if lacking:
        raise ModelError(f"the datum's reference product has no DSB of {' '.join(lacking)}")
    n, svs = len(layout.receivers), np.array(layout.svs)
    use = present_satellites(layout, estimable) & np.isin(svs, list(members))
    out = np.zeros(n + len(svs))
    if use.any():
        r = float(np.mean([fill_ns[s] for s in svs[use]]))
        out[:n], out[n:] = -r, r
    return out


def datum_statement(
    svs_present: Sequence[str],
    members: Sequence[str] | None = None,
    reference_name: str | None = None,
) -> str:
    """One line naming the datum and the satellites it runs over (console, summary.json, Bias-SINEX comments)."""
    if members is None:
        return (
            f"zero mean over the {len(svs_present)} satellites estimated ({' '.join(svs_present)}); a missing "
            "satellite moves all others (--datum-satellites fixes the set)"
        )
    here = [s for s in members if s in svs_present]
    missing = [s for s in members if s not in svs_present]
    text = f"zero mean over the fixed set of {len(members)} satellites ({' '.join(members)})"
    if reference_name:
        text += f", aligned to {reference_name}"
        if missing:
            text += f"; {len(missing)} missing ({' '.join(missing)}) held at the product's values"
    elif missing:
        text += (
            f"; {len(missing)} missing ({' '.join(missing)}): the mean runs over the {len(here)} present, the datum "
            "differs from the full set's"
        )
    return text
