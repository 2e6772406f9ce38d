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

from typing import Any

__all__ = ["AGREE", "DIFFER", "NOT_CHECKABLE", "VERDICTS", "claim", "verdict"]

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
