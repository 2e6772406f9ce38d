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

__all__ = ["present_satellites", "datum_offset_ns", "datum_statement", "error_ratio_interval"]


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


def error_ratio_interval(n_satellites: int, *, level: float = 0.90, datum_dof: int = 1) -> tuple[float, float]:
    """The ``level`` interval that chance gives ``RMS(e/σ)`` of ``n_satellites`` DSB errors ``e`` against a product
    when the stated σ is right: ``n·RMS² ~ χ²_ν`` with ``ν = n − datum_dof``, so the interval is
    ``[√(χ²_{ν,(1−level)/2}/n), √(χ²_{ν,(1+level)/2}/n)]`` (90 %: the 5 % and 95 % quantiles).

    ``datum_dof = 1`` for errors aligned to zero mean over the satellites (the comparison's datum takes one
    degree of freedom). Approximate: it assumes independent errors of equal σ, while the errors of one solution are
    correlated through the datum and the shared receivers — a row outside it misses by more than chance alone
    would give, a row inside it is not proven right. The quantiles are those of
    :func:`~distnav.algorithms.statistics.variance_factor_test`.

    Examples
    --------
    >>> from distnav.models.gnss.datum import error_ratio_interval
    >>> [round(v, 3) for v in error_ratio_interval(15)]
    [0.662, 1.257]
    """
    from distnav.algorithms.statistics import variance_factor_test

    dof = n_satellites - datum_dof
    if dof < 1 or not 0.0 < level < 1.0:
        raise ModelError(f"need n_satellites > datum_dof and 0 < level < 1; got {n_satellites}, {datum_dof}, {level}")
    _, (lo, hi), _ = variance_factor_test(float(dof), float(dof), level=1.0 - level)
    return float(np.sqrt(lo * dof / n_satellites)), float(np.sqrt(hi * dof / n_satellites))
