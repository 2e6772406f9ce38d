"""In-process equals MPI: the same runs under ``mpiexec -n 4`` give the same numbers; failures end the job.

Each test launches ``mpiexec`` from inside pytest with a timeout and no standard input.
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("mpi4py", reason="the mpi extra is not installed (pip install '.[mpi]' in the clone)")

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE / "mpi"))
from cases import CASES  # noqa: E402

pytestmark = pytest.mark.mpi
N_RANKS = 4
BITWISE = {"estimates", "sent", "received", "bytes", "per_round", "count", "edge_sum", "bcast_sum", "mixed"}


def _mpiexec() -> str:
    local = Path(sys.executable).parent / "mpiexec"
    exe = str(local) if local.exists() else shutil.which("mpiexec")
    if exe is None:
        pytest.fail("mpi4py is installed but no mpiexec was found (pip install mpich)")
    return exe


def _launch(args: list[str], *, n: int = N_RANKS, timeout: float = 120) -> subprocess.CompletedProcess[str]:
    env = dict(os.environ, PYTHONUNBUFFERED="1")
    return subprocess.run(
        [_mpiexec(), "-n", str(n), sys.executable, "-m", "mpi4py", *args],
        stdin=subprocess.DEVNULL,
        capture_output=True,
        text=True,
        timeout=timeout,
        env=env,
    )


@pytest.fixture(scope="module")
def mpi_results(tmp_path_factory) -> dict[str, np.ndarray]:
    out = tmp_path_factory.mktemp("mpi") / "cases.npz"
    proc = _launch([str(HERE / "mpi" / "run_cases.py"), str(out)], timeout=300)
    assert proc.returncode == 0, proc.stderr[-3000:]
    with np.load(out) as data:
        return {k: data[k] for k in data.files}


@pytest.mark.parametrize("name", list(CASES))
def test_mpi_equals_inprocess(name, mpi_results):
    ref = CASES[name]("inprocess")
    for key, value in ref.items():
        got = mpi_results[f"{name}/{key}"]
        assert got.shape == np.shape(value), f"{name}/{key}"
        if key in BITWISE:
            # the MPI exchange sums every row in the in-process order: node results agree bit for bit
            # (NaN where a node's state is not yet estimable: in the same places on both backends)
            same = np.array_equal(got, value, equal_nan=got.dtype.kind in "fc")
            assert same, f"{name}/{key}: max diff {np.nanmax(np.abs(got - value))}"
        else:
            # network-wide sums (allreduce) add partial sums in another order: equal to rounding (the CKF relay's
            # first-epoch σ of a poorly observed node: 1.8e-12 relative)
            np.testing.assert_allclose(got, value, rtol=1e-11, atol=1e-14, err_msg=f"{name}/{key}")


def test_cli_reproduce_under_mpi_writes_the_same_file(tmp_path):
    from distnav.cli import main

    proc = _launch(
        [
            "-m",
            "distnav",
            "reproduce",
            "consensus",
            "--backend",
            "mpi",
            "--ranks",
            str(N_RANKS),
            "--quick",
            "--no-progress",
            "--out",
            str(tmp_path / "mpi"),
        ]
    )
    assert proc.returncode == 0, proc.stderr[-3000:]
    assert main(["reproduce", "consensus", "--quick", "--no-progress", "--out", str(tmp_path / "local")]) == 0
    a = (tmp_path / "mpi" / "results.json").read_bytes()
    b = (tmp_path / "local" / "results.json").read_bytes()
    assert a == b
    assert json.loads(a)["final_max_abs_deviation"]["P3"] > 0


def test_hostfile_launch_as_in_the_slurm_recipe(tmp_path):
    """docs/scale.md: the multi-host launch line, here with a hostfile naming localhost (4 slots)."""
    from distnav.cli import main

    hosts = tmp_path / "hosts"
    hosts.write_text("localhost:4\n")
    env = dict(os.environ, PYTHONUNBUFFERED="1")
    proc = subprocess.run(
        [
            _mpiexec(),
            "-f",
            str(hosts),
            "-n",
            "4",
            sys.executable,
            "-m",
            "mpi4py",
            "-m",
            "distnav",
            "reproduce",
            "consensus",
            "--backend",
            "mpi",
            "--ranks",
            "4",
            "--quick",
            "--no-progress",
            "--out",
            str(tmp_path / "mpi"),
        ],
        stdin=subprocess.DEVNULL,
        capture_output=True,
        text=True,
        timeout=180,
        env=env,
    )
    assert proc.returncode == 0, proc.stderr[-3000:]
    assert main(["reproduce", "consensus", "--quick", "--no-progress", "--out", str(tmp_path / "local")]) == 0
    assert (tmp_path / "mpi" / "results.json").read_bytes() == (tmp_path / "local" / "results.json").read_bytes()


@pytest.mark.parametrize("mode", ["raise", "die"])
def test_failing_rank_ends_whole_job(tmp_path, mode):
    t0 = time.perf_counter()
    proc = _launch([str(HERE / "mpi" / "fail_rank.py"), "2", mode, str(tmp_path / "out")], timeout=60)
    elapsed = time.perf_counter() - t0
    assert proc.returncode != 0
    assert elapsed < 30
    if mode == "raise":
        assert "error on MPI rank 2 of 4: RuntimeError: injected failure" in proc.stderr
    # no half-written output
    assert not (tmp_path / "out" / "results.json").exists()
    leftovers = list((tmp_path / "out").glob("*")) if (tmp_path / "out").exists() else []
    assert not [p for p in leftovers if p.suffix in {".json", ".tmp"}]


def test_rank_count_mismatch_is_reported(tmp_path):
    proc = _launch(
        [
            "-m",
            "distnav",
            "reproduce",
            "consensus",
            "--backend",
            "mpi",
            "--ranks",
            "3",
            "--quick",
            "--no-progress",
            "--out",
            str(tmp_path),
        ],
        n=2,
    )
    assert proc.returncode != 0
    assert "--ranks 3 was asked for but MPI reports 2 rank(s)" in proc.stderr


def test_partition_rules():
    from distnav.errors import ExchangeError
    from distnav.exchange import mpi as exchange_mpi
    from distnav.network import Graph, builders
    from distnav.network.partition import partition_nodes

    assert exchange_mpi.partition_nodes is partition_nodes  # the old import path still works

    g = builders.path(6)
    assert partition_nodes(g, 3, "block").tolist() == [0, 0, 1, 1, 2, 2]
    assert partition_nodes(g, 6, "node").tolist() == list(range(6))
    assert np.bincount(partition_nodes(g, 4, "rcm")).min() >= 1
    with pytest.raises(ExchangeError, match="one rank per node: launch 6 ranks, not 3"):
        partition_nodes(g, 3, "node")
    with pytest.raises(ExchangeError, match="7 ranks for 6 nodes"):
        partition_nodes(g, 7, "block")
    with pytest.raises(ExchangeError, match="unknown partition"):
        partition_nodes(g, 2, "metis")
    with pytest.raises(ExchangeError, match=r"ranks \[1\] would hold no node"):
        partition_nodes(g, 2, np.zeros(6, int))
    with pytest.raises(ExchangeError, match="owner ranks must be in 0..1"):
        partition_nodes(g, 2, np.full(6, 2))
    # RCM keeps far fewer links cut than contiguous ids on a shuffled geometric network
    base = builders.connected_random_geometric(2000, mean_degree=8, rng=np.random.default_rng(0))
    perm = np.random.default_rng(1).permutation(2000)
    shuffled = Graph.from_links(2000, perm[base.links])

    def cut(owner: np.ndarray) -> int:
        return int((owner[shuffled.src] != owner[shuffled.dst]).sum())

    assert cut(partition_nodes(shuffled, 4, "rcm")) < 0.25 * cut(partition_nodes(shuffled, 4, "block"))


def test_real_data_command_under_mpi_writes_the_same_files(shared_data, tmp_path):
    """`distnav gnss ionosphere --backend mpi` (a CKF on 5 real Dutch receivers) equals the in-process run."""
    from distnav.cli import main

    d = shared_data / "gnss" / "nl_2021001_short_network_snapshot"
    obs = [str(d / f) for f in ("delf0010.21o", "eijs0010.21d", "wsra0010.21o", "zegv0010.21o", "rovn0010.21o")]
    common = [
        "gnss",
        "ionosphere",
        "--obs",
        *obs,
        "--nav",
        str(d / "cbw10010.21n.gz"),
        "--nav-max-age",
        "24",
        "--kn",
        "4",
        "--no-progress",
    ]
    proc = _launch(["-m", "distnav", *common, "--backend", "mpi", "--ranks", "2", "--out", str(tmp_path / "mpi")], n=2)
    assert proc.returncode == 0, proc.stderr[-3000:]
    assert main([*common, "--out", str(tmp_path / "local")]) == 0
    for name in ("tec_dcb_per_epoch.csv", "dcb_final.csv"):
        assert (tmp_path / "mpi" / name).read_bytes() == (tmp_path / "local" / name).read_bytes(), name
    assert proc.stdout.count("pivot") <= 1  # only rank 0 prints
