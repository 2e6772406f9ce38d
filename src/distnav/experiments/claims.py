"""Paper claims as data: the ``claims`` list an experiment writes into its ``results.json``.

One claim is a flat dict (JSON-ready)::

    {"paper": "003", "where": "Fig. 4", "claim": "P1 ≈ 80 % at k_n = 10, q = 0.2",
     "paper_value": "≈ 0.80", "distnav_value": 0.803, "verdict": "agree",
     "why": "…", "test": "tests/test_experiment_consensus.py::test_paper_like_probabilities"}

``verdict`` is one of :data:`VERDICTS`; ``why`` says how distnav's number was obtained or why it differs or
cannot be checked; ``test`` names the test that fails if the claim changes ("" with the reason in ``why`` if none).
:mod:`distnav.experiments.claims_table` turns the lists of a run into ``docs/claims.md`` and the report summary.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

__all__ = [
    "AGREE",
    "DIFFER",
    "NOT_CHECKABLE",
    "VERDICTS",
    "FULL_ONLY",
    "Missing",
    "Row",
    "checked",
    "claim",
    "get",
    "illustration",
    "rows_of",
    "unchecked",
    "verdict",
]

Row = dict[str, Any]

AGREE = "agree"
DIFFER = "differ"
NOT_CHECKABLE = "not checkable"
VERDICTS = (AGREE, DIFFER, NOT_CHECKABLE)


def verdict(ok: bool | None) -> str:
    """``agree`` / ``differ`` for a checked claim, ``not checkable`` for ``None``."""
    return NOT_CHECKABLE if ok is None else (AGREE if ok else DIFFER)


def claim(
    *,
    paper: str,
    where: str,
    text: str,
    paper_value: Any,
    distnav_value: Any,
    ok: bool | None,
    why: str = "",
    test: str = "",
) -> dict[str, Any]:
    """One row of the claims table (see the module docstring); ``ok`` gives the verdict."""
    return {
        "paper": paper,
        "where": where,
        "claim": text,
        "paper_value": paper_value,
        "distnav_value": distnav_value,
        "verdict": verdict(ok),
        "why": why,
        "test": test,
    }


def unchecked(paper: str, where: str, text: str, paper_value: Any, why: str) -> dict[str, Any]:
    """A "not checkable" row: no distnav value, no test, ``why`` the reason (a field the run lacks, or a statement
    no run can measure: an illustration, unpublished data)."""
    return claim(paper=paper, where=where, text=text, paper_value=paper_value, distnav_value=None, ok=None, why=why)


def illustration(paper: str, where: str, text: str, note: str = "") -> dict[str, Any]:
    """The "not checkable" row of a figure that illustrates without a quantity; ``note`` adds where it is checked."""
    why = "not in results.json: an illustration without a quantity" + (f"; {note}" if note else "")
    return unchecked(paper, where, text, "illustration", why)


# ------------------------------------------------------------------------------------------------ reading a run
class Missing(KeyError):
    """A field a claim needs is absent from the run's ``results.json`` (the row becomes "not checkable")."""


def get(d: Any, *keys: str) -> Any:
    """``d[k1][k2]…``; :class:`Missing` naming the dotted path if any level is absent."""
    for k in keys:
        if not isinstance(d, dict) or k not in d:
            raise Missing(".".join(keys))
        d = d[k]
    return d


#: The stated reason of a row no unit test pins: its number exists only at the full run's size (docs/claims.md).
FULL_ONLY = "no unit test: only the full run decides it — "


def checked(
    *,
    paper: str,
    where: str,
    text: str,
    paper_value: Any,
    test: str,
    measure: Callable[[], tuple[Any, bool | None, str]],
) -> dict[str, Any]:
    """One row whose ``(distnav_value, ok, why)`` come from ``measure()`` (which reads the run's results); if a
    field is missing the row keeps its claim and says "not checkable: results.json lacks …"."""
    try:
        value, ok, why = measure()
    except (Missing, KeyError, TypeError, ValueError, IndexError, ZeroDivisionError) as exc:
        return unchecked(paper, where, text, paper_value, f"results.json lacks {exc}")
    if not test and ok is not None and FULL_ONLY not in why:
        why += "; no test pins it yet"
    return claim(
        paper=paper, where=where, text=text, paper_value=paper_value, distnav_value=value, ok=ok, why=why, test=test
    )


def rows_of(makers: list[Callable[[], Row]], paper: str) -> list[Row]:
    """The rows the ``makers`` build; one that finds a field missing gives a "not checkable" row instead."""
    out = []
    for make in makers:
        try:
            row = make()
            if not row["test"] and FULL_ONLY not in row["why"]:
                row["why"] += "; no test pins it yet"
            out.append(row)
        except (Missing, KeyError, TypeError, ValueError) as exc:
            out.append(unchecked(paper, "—", "(a claim this run cannot evaluate)", None, f"results.json lacks {exc}"))
    return out
