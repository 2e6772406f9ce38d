"""`distnav reproduce codebias`: the 110-station network and a small run of the reproduction."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from distnav.experiments.codebias import N_LINKS, N_STATIONS, synthetic_igs_network
from distnav.experiments.common import ExperimentContext, Progress


def test_network_matches_paper_counts() -> None:
    from distnav.network.constraint_nodes import choose_constraint_nodes

    net = synthetic_igs_network(np.random.default_rng([0, 1]))
    g = net.graph
    assert g.n_nodes == N_STATIONS == 110 and g.n_links == N_LINKS == 118
    assert g.is_connected
    C = choose_constraint_nodes(g, "min_cover")
    # every link touches a hub, and each hub has ≥ 2 single-link stations: the 9 hubs are the minimum cover
    assert C.size == 9 and C.optimal
    assert sorted(C.nodes.tolist()) == sorted(net.hubs.tolist())
    assert C.unused_links.shape[0] == 0


def test_small_reproduction(tmp_path: Path) -> None:
    from distnav.experiments import codebias

    ctx = ExperimentContext(
        out_dir=tmp_path, quick=True, progress=Progress(enabled=False), options={"epochs": 60, "iterations": 300}
    )
    res = codebias.run(ctx)
    saved = json.loads((tmp_path / "results.json").read_text())
    assert saved["n_nodes"] == 110 and saved["n_links"] == 118 and saved["n_constraint_nodes"] == 9
    assert set(saved["iterations_to_1e-3"]) == {"5", "0.5", "0.05", "0.005"}
    assert all(v is None or isinstance(v, int) for v in saved["iterations_to_1e-3"].values())
    # the model's centralized solution is the BLUE of distnav.algorithms.lsq.blue on the compressed problem
    assert res["model_vs_lsq_blue_max_abs_m"] < 1e-9
    # ADMM with ρ = 0.5 (per-epoch scale) reaches the centralized solution to 1 mm within the run
    assert saved["iterations_to_1e-3"]["0.5"] is not None
    assert saved["final_max_distance_m"]["0.5"] < 1e-3
    # the paper's ρ ordering (Fig. 9): ρ = 0.5 fastest, ρ = 5 slow from zero, smaller ρ not faster
    final = saved["final_max_distance_m"]
    assert final["0.5"] < final["0.05"] < final["0.005"]
    assert final["5"] > 100 * final["0.5"]
    its = saved["iterations_to_1e-2"]
    assert its["0.5"] is not None and all(v is None or v > its["0.5"] for k, v in its.items() if k != "0.5")
    assert "headline" in saved and saved["rho_scale"] == "epoch"
    # issue 27: ADMM's traffic beside gathering every station's data (observations or normals) at one station
    cmp = saved["communication_vs_gather"]["0.5"]
    assert cmp["distributed"]["bytes"] == saved["communication"]["0.5"]["bytes"]
    assert cmp["gather"]["unreachable_nodes"] == 0 and 0 < cmp["gather"]["data_bytes"] < cmp["distributed"]["bytes"]
    # Fig. 8: the recursive centralized solution is consistent with the truth (χ²/p of x̂ − truth near 1)
    assert 0.3 < saved["chi2_per_dof_vs_truth"] < 3.0
    for f in ("fig7_network.png", "fig8_centralized.png", "fig9_rho.png", "fig10_init.png", "fig11_per_node.png"):
        assert (tmp_path / f).stat().st_size > 1000


@pytest.mark.mpi
def test_mpi_backend_gives_the_same_numbers(tmp_path: Path) -> None:
    """The reproduction under ``mpiexec -n 2 ... --backend mpi`` equals the in-process run."""
    pytest.importorskip("mpi4py", reason="the mpi extra is not installed (pip install 'distnav-estimation[mpi]')")
    local = Path(sys.executable).parent / "mpiexec"
    exe = str(local) if local.exists() else shutil.which("mpiexec")
    if exe is None:
        pytest.skip("no mpiexec")
    opts = ["--quick", "--epochs", "40", "--iterations", "250", "--no-progress"]
    proc = subprocess.run(
        [
            exe,
            "-n",
            "2",
            sys.executable,
            "-m",
            "mpi4py",
            "-m",
            "distnav",
            "reproduce",
            "codebias",
            "--backend",
            "mpi",
            "--out",
            str(tmp_path / "mpi"),
            *opts,
        ],
        stdin=subprocess.DEVNULL,
        capture_output=True,
        text=True,
        timeout=240,
        env=dict(os.environ, PYTHONUNBUFFERED="1"),
    )
    assert proc.returncode == 0, proc.stderr[-2000:]
    from distnav.cli import main

    assert main(["reproduce", "codebias", "--out", str(tmp_path / "inproc"), *opts]) == 0
    a = json.loads((tmp_path / "mpi" / "results.json").read_text())
    b = json.loads((tmp_path / "inproc" / "results.json").read_text())
    assert a["iterations_to_1e-3"] == b["iterations_to_1e-3"]
    assert a["iterations_to_1e-3_by_init_rho_0.5"] == b["iterations_to_1e-3_by_init_rho_0.5"]
    for k, v in b["final_max_distance_m"].items():
        assert a["final_max_distance_m"][k] == pytest.approx(v, rel=1e-9, abs=1e-15)


def test_real_constellation_option(shared_data: Path) -> None:
    from distnav.experiments.codebias import constellation
    from distnav.models.gnss.orbits import datetime_from_gps_seconds

    orbit, svs, t0, text = constellation(
        str(shared_data / "gnss/igs_2024010_bele_dgar/BRDC00IGS_R_20240100000_01D_MN.rnx.gz")
    )
    assert "G01" not in svs  # flagged unhealthy all day in the broadcast file
    assert set(svs) <= {"G03", "G06", "G08", "G09", "G10", "G24", "G25", "G26", "G27", "G30", "G32"}
    assert len(svs) >= 8 and "BRDC00IGS" in text
    assert datetime_from_gps_seconds(np.array(t0)) == np.datetime64("2024-01-10T01:00:00")
    assert np.isfinite(orbit.positions_ecef(np.array([t0]), list(svs))).all()
    _, svs_syn, _, text_syn = constellation()
    assert len(svs_syn) == 12 and "synthetic" in text_syn
