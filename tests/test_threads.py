"""One BLAS thread per rank under an MPI launch (distnav._threads), the user's choice kept."""

from __future__ import annotations

import os
import subprocess
import sys

import pytest

from distnav._threads import MPI_LAUNCH_VARIABLES, THREAD_VARIABLES, one_blas_thread_under_mpi

_COUNT = (
    "import distnav, numpy; from distnav._blas import _openblas_handles; "
    "print([g() for _, g in _openblas_handles()][0], __import__('os').environ.get('OPENBLAS_NUM_THREADS'))"
)


def test_set_under_mpi_launch_only() -> None:
    env = {"PMI_SIZE": "2", "PMI_RANK": "0"}
    assert one_blas_thread_under_mpi(env, numpy_imported=False)
    assert env["OPENBLAS_NUM_THREADS"] == "1" and env["OMP_NUM_THREADS"] == "1"
    for launcher in ("OMPI_COMM_WORLD_SIZE", "MPI_LOCALNRANKS", "PMIX_RANK"):
        env = {launcher: "4"}
        assert one_blas_thread_under_mpi(env, numpy_imported=False) and env["OPENBLAS_NUM_THREADS"] == "1"
    env = {"HOME": "/root"}
    assert not one_blas_thread_under_mpi(env, numpy_imported=False) and env == {"HOME": "/root"}


@pytest.mark.parametrize("user", ["OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS", "GOTO_NUM_THREADS"])
def test_the_users_thread_count_is_kept(user: str) -> None:
    env = {"PMI_SIZE": "2", user: "2"}
    assert not one_blas_thread_under_mpi(env, numpy_imported=False)
    assert env == {"PMI_SIZE": "2", user: "2"}


def test_nothing_once_numpy_is_imported() -> None:
    env = {"PMI_SIZE": "2"}
    assert not one_blas_thread_under_mpi(env, numpy_imported=True) and env == {"PMI_SIZE": "2"}


def _threads_in_child(**extra: str) -> tuple[int, str]:
    drop = (*THREAD_VARIABLES, *MPI_LAUNCH_VARIABLES)
    env = {k: v for k, v in os.environ.items() if k not in drop}
    env.update(extra)
    out = subprocess.run([sys.executable, "-c", _COUNT], env=env, capture_output=True, text=True, check=True)
    n, var = out.stdout.split()
    return int(n), var


@pytest.mark.skipif((os.cpu_count() or 1) < 2, reason="OpenBLAS starts one thread on a one-core machine anyway")
def test_openblas_really_starts_one_thread() -> None:
    """``import distnav`` before numpy in a process an MPI launcher started: OpenBLAS runs one thread."""
    try:
        default, _ = _threads_in_child()
    except (subprocess.CalledProcessError, IndexError, ValueError):  # pragma: no cover
        pytest.skip("numpy's OpenBLAS not found")
    assert default > 1  # without a launcher: OpenBLAS's own default (one per core)
    assert _threads_in_child(PMI_SIZE="2", PMI_RANK="0") == (1, "1")
    assert _threads_in_child(PMI_SIZE="2", OPENBLAS_NUM_THREADS="2") == (2, "2")
