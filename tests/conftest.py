"""Shared fixtures: the ../shared data folder (skips with a reason where it is absent)."""

from __future__ import annotations

import fcntl
import os
import shutil
from collections.abc import Callable
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


def once_per_run(tmp_path_factory: pytest.TempPathFactory, name: str, make: Callable[[Path], None]) -> Path:
    """The folder ``make(folder)`` fills, made once per pytest run and shared by every xdist worker (the base
    temporary folder's parent is common to the workers; a file lock makes the others wait, then read). A ``make``
    that raises leaves no folder behind, so each test that asks fails with the error, none reads a partial run."""
    root = tmp_path_factory.getbasetemp()
    if os.environ.get("PYTEST_XDIST_WORKER"):
        root = root.parent
    out = root / name
    with open(root / f"{name}.lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        if not (out / ".complete").exists():
            shutil.rmtree(out, ignore_errors=True)
            try:
                make(out)
            except BaseException:
                shutil.rmtree(out, ignore_errors=True)
                raise
            (out / ".complete").touch()
    return out


@pytest.fixture(scope="session")
def bele_glonass_day(shared_data: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """``gnss ionosphere --system R`` on BELE's whole day (C1C-C2C, CAS compared, --kn 0): the run both
    test_gnss_multisystem (DSBs against CAS, the channel split) and test_gnss_sigmaterms (σ against CAS) check —
    one run of about 40 s instead of two (the day with ``--tlim 00:00 23:59:30`` writes the same files)."""
    d = shared_data / "gnss" / "igs_2024010_bele_dgar"

    def make(out: Path) -> None:
        from distnav.cli import main

        args = ["gnss", "ionosphere", "--system", "R", "--obs", str(d / "BELE00BRA_R_20240100000_01D_30S_MO.crx.gz")]
        args += ["--nav", str(d / "BRDC00IGS_R_20240100000_01D_MN.rnx.gz"), "--l1-code", "C1C", "--l2-code", "C2C"]
        args += ["--bias", str(d / "CAS0OPSRAP_20240100000_01D_01D_DCB.BIA.gz"), "--kn", "0", "--no-progress"]
        assert main([*args, "--out", str(out)]) == 0

    return once_per_run(tmp_path_factory, "bele_glonass_day", make)


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
