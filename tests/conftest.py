"""Shared fixtures: the ../shared data folder (skips with a reason where it is absent)."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pytest

REPO = Path(__file__).resolve().parents[1]


def _shared_root() -> Path | None:
    env = os.environ.get("DISTNAV_SHARED")
    candidates = [Path(env)] if env else []
    candidates += [REPO.parent / "shared", REPO.parent.parent / "shared"]
    for c in candidates:
        if (c / "data").is_dir():
            return c
    return None


SHARED = _shared_root()

# MPICH ranks yield the core while they wait for a message instead of spinning on it: the tests start mpiexec -n 4
# on CI's 2 cores, where spinning ranks take the core from the rank that has the work (the MPI cases ran in 69 s and
# 50 s with it against 123 s and 140 s without, the same numbers; a setting of MPICH only, no effect on results)
os.environ.setdefault("MPIR_CVAR_ENABLE_HEAVY_YIELD", "1")


@pytest.fixture(scope="session")
def shared_data() -> Path:
    """``../shared/data``; tests using it skip (with the reason) on a clone without it."""
    if SHARED is None:
        pytest.skip(
            "../shared/data is absent (a fresh clone without it): the real GNSS RINEX/bias files and the UWB "
            "logs come from public archives named in each data folder's PROVENANCE.md; put them in "
            "../shared/data or point DISTNAV_SHARED at the folder holding data/"
        )
    return SHARED / "data"


@pytest.fixture
def rng() -> np.random.Generator:
    return np.random.default_rng(12345)


def assert_lost_named_everywhere(summary: dict, victim: int, rest: list[int], after_step: int) -> list[dict]:
    """A field run with one node killed on purpose: every other node finished, none failed or stopped, and each
    names the victim as its only lost node at one and the same step, not before it died. Returns their results."""
    assert summary["crashed_on_purpose"] == [victim], summary
    assert summary["finished"] == rest and summary["failed"] == [] and summary["stopped"] == [], summary
    nodes = [summary["nodes"][str(i)] for i in rest]
    steps = {r["lost_nodes"][str(victim)] for r in nodes}
    assert all(list(r["lost_nodes"]) == [str(victim)] for r in nodes)
    assert len(steps) == 1 and steps.pop() >= after_step
    return nodes
