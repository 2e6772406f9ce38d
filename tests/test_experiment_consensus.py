"""`distnav reproduce consensus` and `distnav demo`: files written, schema of results.json, paper facts."""

from __future__ import annotations

import json

import numpy as np

from distnav.cli import main
from distnav.experiments.common import ExperimentContext, Progress
from distnav.experiments.consensus import run, static_network, switching_network


def test_networks_have_paper_shapes():
    rng = np.random.default_rng(0)
    g = static_network(rng)
    assert g.n_nodes == 20 and g.n_links == 49 and g.is_connected
    sw = switching_network(rng)
    assert [s.n_links for s in sw.sessions] == [7, 6, 8, 7]
    assert all(s.degrees.max() <= 1 for s in sw.sessions)
    assert sw.union.is_connected


def test_reproduce_consensus_writes_results(tmp_path):
    ctx = ExperimentContext(out_dir=tmp_path, quick=True, progress=Progress(enabled=False))
    res = run(ctx)
    data = json.loads((tmp_path / "results.json").read_text())
    assert set(data["slem"]) == {"P1", "P2", "P3"}
    assert set(data["final_max_abs_deviation"]) == {"P1", "P2", "P3", "P4"}
    for p in ("P1", "P2", "P3", "P4"):
        for kn in ("10", "20", "30"):
            curve = np.array(data["probability"][p][kn])
            assert curve.shape == (len(data["q"]),)
            assert np.all(np.diff(curve) >= 0) and 0 <= curve[0] <= curve[-1] <= 1
        # more iterations never lower the probability
        assert np.all(np.array(data["probability"][p]["30"]) >= np.array(data["probability"][p]["10"]) - 0.02)
    # paper's qualitative facts on our networks: P2 is the slowest protocol; all λ < 1
    assert max(data["slem"].values()) == data["slem"]["P2"] < 1
    assert abs(res["average"] - 5.0) < 1e-12
    for name in ("fig2_networks.png", "fig3_iterations.png", "fig4_probability.png"):
        assert (tmp_path / name).stat().st_size > 10_000


def test_cli_demo_writes_report(tmp_path, capsys):
    out = tmp_path / "demo"
    assert main(["demo", "--out", str(out), "--only", "consensus", "--no-progress"]) == 0
    html = (out / "index.html").read_text()
    assert "consensus/fig4_probability.png" in html and "λ_(n-1) P3" in html
    assert (out / "consensus" / "results.json").exists()
    assert "report:" in capsys.readouterr().out


def test_cli_reproduce_and_errors(tmp_path, capsys):
    assert main(["reproduce", "consensus", "--out", str(tmp_path / "c"), "--quick", "--no-progress"]) == 0
    assert (tmp_path / "c" / "results.json").exists()
    # no temporary files are left behind
    assert not [p for p in (tmp_path / "c").iterdir() if p.name.endswith(".tmp")]


def test_cli_network_random_keeps_the_random_draw(tmp_path):
    assert main(["reproduce", "consensus", "--network", "random", "--out", str(tmp_path / "r"), "--quick",
                 "--no-progress"]) == 0
    data = json.loads((tmp_path / "r" / "results.json").read_text())
    ref = static_network(np.random.default_rng([0, 1]))
    assert data["network"]["kind"] == "random" and data["network"]["search"] is None
    assert data["network"]["static"]["links"] == ref.links.tolist()
