"""`distnav reproduce consensus` and `distnav demo`: files written, schema of results.json, paper facts."""

from __future__ import annotations

import json
import sys

import numpy as np
import pytest

from distnav.cli import main
from distnav.experiments.common import ExperimentContext, Progress
from distnav.experiments.consensus import run, static_network, switching_network
from distnav.experiments.consensus_network import PAPER_LIKE

PAPER_SLEM = {"P1": 0.92, "P2": 0.97, "P3": 0.91}  # paper 003 §3.3


def _dense_protocols(links: list[list[int]], n: int = 20) -> dict[str, np.ndarray]:
    """Table 1 of paper 003 written out with dense matrices, independently of distnav.network.weights."""
    A = np.zeros((n, n))
    for i, j in links:
        A[i, j] = A[j, i] = 1.0
    d = A.sum(1)
    lap = np.diag(d) - A
    M = A / (1.0 + np.maximum.outer(d, d))
    return {
        "P1": np.eye(n) - lap / d.max(),
        "P2": np.eye(n) - lap / n,
        "P3": M + np.diag(1.0 - M.sum(1)),
        "P4": np.eye(n) - lap / 2.0,
    }  # P4 only on a matching: w_ij = w_ii = 1/2


def _product(mats: list[np.ndarray], kn: int) -> np.ndarray:
    out = np.eye(mats[0].shape[0])
    for k in range(kn):
        out = mats[k % len(mats)] @ out
    return out


def _prob_at(L: np.ndarray, q: float, samples: int = 50_000, seed: int = 123) -> float:
    r = np.random.default_rng(seed).standard_normal((samples, L.shape[0]))
    return float(np.mean(np.abs(r @ (L - 1.0 / L.shape[0]).T).max(axis=1) <= q))


@pytest.fixture(scope="module")
def quick_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("consensus")
    ctx = ExperimentContext(out_dir=out, quick=True, progress=Progress(enabled=False))
    return out, run(ctx)


def test_paper_like_slem():
    """λ_(n−1) of P1/P2/P3 on the default network equals the paper's 0.92 / 0.97 / 0.91 to two decimals."""
    W = _dense_protocols(PAPER_LIKE["links"])
    slem = {p: float(np.sort(np.abs(np.linalg.eigvalsh(W[p])))[-2]) for p in PAPER_SLEM}
    assert {p: round(v, 2) for p, v in slem.items()} == PAPER_SLEM
    assert min(slem, key=slem.__getitem__) == "P3" and max(slem, key=slem.__getitem__) == "P2"


def test_paper_like_probabilities():
    """Fig. 4 at q = 0.2: P1 ≈ 80 %, P2 < 5 % at k_n = 10; P2 ≈ 80 %, P1, P3 ≈ 100 % at k_n = 30 (paper 003 §3.3)."""
    W = _dense_protocols(PAPER_LIKE["links"])
    p = {(name, kn): _prob_at(_product([W[name]], kn), 0.2) for name in ("P1", "P2", "P3") for kn in (10, 30)}
    assert abs(p["P1", 10] - 0.80) <= 0.05 and p["P2", 10] < 0.05
    assert abs(p["P2", 30] - 0.80) <= 0.05 and min(p["P1", 30], p["P3", 30]) >= 0.98
    sessions = [_dense_protocols(s)["P4"] for s in PAPER_LIKE["sessions"]]
    for kn in (10, 20, 30):
        p4 = _prob_at(_product(sessions, kn), 0.2)
        p2 = _prob_at(_product([W["P2"]], kn), 0.2)
        p3 = _prob_at(_product([W["P3"]], kn), 0.2)
        assert p2 < p4 <= p3 + 0.01, kn  # P4 better than P2 (Fig. 4), P3 still the best


def test_protocol_ordering(quick_run):
    """P3 highest and P2 lowest probabilities at every q and k_n; P4 above P2; Fig. 3's rates; claims all agree."""
    _, res = quick_run
    prob = {p: {k: np.asarray(v) for k, v in c.items()} for p, c in res["probability"].items() if p != "q"}
    for kn in ("10", "20", "30"):
        for p in prob:
            assert np.all(prob["P3"][kn] >= prob[p][kn] - 0.01), (p, kn)
            assert np.all(prob["P2"][kn] <= prob[p][kn] + 0.01), (p, kn)
        assert np.mean(prob["P4"][kn] - prob["P2"][kn]) > 0.05, kn
    dev = res["final_max_abs_deviation"]
    assert max(dev["P1"], dev["P3"]) < min(dev["P2"], dev["P4"])
    assert {c["verdict"] for c in res["claims"]} == {"agree"}
    here = sys.modules[__name__]
    for c in res["claims"]:  # every claim names a test of this file that asserts it
        assert c["test"].startswith("tests/test_experiment_consensus.py::")
        assert callable(getattr(here, c["test"].split("::")[1]))


def test_networks_have_paper_shapes():
    rng = np.random.default_rng(0)
    g = static_network(rng)
    assert g.n_nodes == 20 and g.n_links == 49 and g.is_connected
    sw = switching_network(rng)
    assert [s.n_links for s in sw.sessions] == [7, 6, 8, 7]
    assert all(s.degrees.max() <= 1 for s in sw.sessions)
    assert sw.union.is_connected


def test_reproduce_consensus_writes_results(quick_run):
    tmp_path, res = quick_run
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
    # issue 27: each protocol's traffic beside gathering the 20 values (8 B each) at one node
    for p in ("P1", "P2", "P3", "P4"):
        cmp = data["communication_vs_gather"][p]
        assert cmp["distributed"]["bytes"] == data["communication"][p]["bytes"]
        assert cmp["gather"]["data_bytes"] == 8 * 20 and cmp["gather"]["unreachable_nodes"] == 0
        assert cmp["ratio_bytes"] == pytest.approx(cmp["distributed"]["bytes"] / cmp["gather"]["total_hop_bytes"])
    for name in ("fig2_networks.png", "fig3_iterations.png", "fig4_probability.png"):
        assert (tmp_path / name).stat().st_size > 10_000


def test_cli_demo_writes_report(tmp_path, capsys):
    out = tmp_path / "demo"
    assert main(["demo", "--out", str(out), "--only", "consensus", "--no-progress"]) == 0
    html = (out / "index.html").read_text()
    assert "consensus/fig4_probability.png" in html and "λ_(n-1) P3" in html
    assert "11 paper claims checked by this run: <b>11 agree</b>" in html
    from test_report import assert_links_resolve  # tests/ is on sys.path (pytest prepend mode)

    parser = assert_links_resolve(out)
    assert parser.figures == parser.captions == 3
    assert (out / "consensus" / "results.json").exists()
    assert "report:" in capsys.readouterr().out


def test_cli_reproduce_and_errors(tmp_path, capsys):
    assert main(["reproduce", "consensus", "--out", str(tmp_path / "c"), "--quick", "--no-progress"]) == 0
    assert (tmp_path / "c" / "results.json").exists()
    # no temporary files are left behind
    assert not [p for p in (tmp_path / "c").iterdir() if p.name.endswith(".tmp")]


def test_cli_network_random_keeps_the_random_draw(tmp_path):
    assert (
        main(
            ["reproduce", "consensus", "--network", "random", "--out", str(tmp_path / "r"), "--quick", "--no-progress"]
        )
        == 0
    )
    data = json.loads((tmp_path / "r" / "results.json").read_text())
    ref = static_network(np.random.default_rng([0, 1]))
    assert data["network"]["kind"] == "random" and data["network"]["search"] is None
    assert data["network"]["static"]["links"] == ref.links.tolist()
