"""Paper claims as data: the ``claims`` list an experiment writes into its ``results.json``.

A paper's claims are a table of :class:`Claim` rows (data: where, the statement, the paper's value, the test that
pins it, and the measure reading distnav's value from a run), turned into rows by one builder, :func:`rows_from`;
a new claim is one :class:`Claim` line in its paper's table (``experiments/claims_paper<NNN>.py``) and, when the
run must be read, its measure beside it.

One row is a flat dict (JSON-ready)::

    {"paper": "003", "where": "Fig. 4", "claim": "P1 ≈ 80 % at k_n = 10, q = 0.2",
     "paper_value": "≈ 0.80", "distnav_value": 0.803, "verdict": "agree",
     "why": "…", "test": "tests/test_experiment_consensus.py::test_paper_like_probabilities"}

``verdict`` is one of :data:`VERDICTS`; ``why`` says how distnav's number was obtained or why it differs or
cannot be checked; ``test`` names the test that fails if the claim changes ("" with the reason in ``why`` if none).
:mod:`distnav.experiments.claims_table` turns the lists of a run into ``docs/claims.md`` and the report summary.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable
from functools import partial
from typing import Any, NamedTuple

__all__ = [
    "AGREE",
    "DIFFER",
    "NOT_CHECKABLE",
    "VERDICTS",
    "FULL_ONLY",
    "Claim",
    "Measure",
    "Missing",
    "Row",
    "checked",
    "claim",
    "get",
    "illustrated",
    "rows_from",
    "stated",
    "unchecked",
    "unit_tested",
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


#: What a claim's measure returns from a run's results: ``(distnav_value, ok, why)``; ``ok`` None: not checkable.
Measure = Callable[[dict[str, Any]], tuple[Any, bool | None, str]]


class Claim(NamedTuple):
    """One claim of a paper as a row of data, read by :func:`rows_from`."""

    where: str  #: figure / table / section of the paper
    text: str  #: the paper's statement
    paper_value: Any  #: the paper's value (or "illustration", "algorithm", "(open)")
    test: str  #: the test that fails if distnav's side changes ("" with the reason in the measure's ``why``)
    measure: Measure  #: reads ``(distnav_value, ok, why)`` from the run's results


def rows_from(paper: str, table: Iterable[Claim], r: dict[str, Any]) -> list[Row]:
    """The rows of ``table`` on the run's results ``r``: one :func:`checked` row per claim (a field the run lacks
    makes that row "not checkable", its claim kept)."""
    return [
        checked(
            paper=paper,
            where=c.where,
            text=c.text,
            paper_value=c.paper_value,
            test=c.test,
            measure=partial(c.measure, r),
        )
        for c in table
    ]


def _stated(why: str, r: dict[str, Any]) -> tuple[Any, bool | None, str]:
    return None, None, why


def stated(why: str) -> Measure:
    """The measure of a claim no run can check: "not checkable", ``why`` the reason."""
    return partial(_stated, why)


def illustrated(note: str = "") -> Measure:
    """The measure of a figure that illustrates without a quantity; ``note`` adds where it is checked."""
    return stated("not in results.json: an illustration without a quantity" + (f"; {note}" if note else ""))


def _unit_tested(how: str, r: dict[str, Any]) -> tuple[Any, bool | None, str]:
    return "implemented", True, "not in results.json: a unit test compares it " + how


def unit_tested(how: str) -> Measure:
    """The measure of an algorithm box pinned by a unit test (the claim's ``test``) against an independent form."""
    return partial(_unit_tested, how)
