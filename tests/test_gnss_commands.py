"""`distnav gnss codebias` / `distnav gnss compare` on real IGS data against CAS and GFZ products, and errors."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from distnav.cli import main
from distnav.commands.gnss import compare_with_products, default_graph, load_edges
from distnav.errors import DataFileError, ModelError

IGS = "gnss/igs_2024010_bele_dgar"
NL = "gnss/nl_2021001_short_network_snapshot"


@pytest.fixture(scope="module")
def run_dir(shared_data: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """BELE (RINEX 3, C5X) + DGAR (RINEX 2, C5Q), 2024-01-10 00:00–03:00, broadcast orbits, compared with CAS."""
    d = shared_data / IGS
    out = tmp_path_factory.mktemp("codebias")
    rc = main(
        [
            "gnss",
            "codebias",
            "--obs",
            str(d / "BELE00BRA_R_20240100000_01D_30S_MO.crx.gz"),
            str(d / "dgar0100.24o.gz"),
            "--nav",
            str(d / "BRDC00IGS_R_20240100000_01D_MN.rnx.gz"),
            "--tlim",
            "2024-01-10T00:00",
            "2024-01-10T03:00",
            "--out",
            str(out),
            "--bias",
            str(d / "CAS0OPSRAP_20240100000_01D_01D_DCB.BIA.gz"),
            "--no-progress",
        ]
    )
    assert rc == 0
    return out


def test_codebias_outputs(run_dir: Path) -> None:
    est = json.loads((run_dir / "codebias.json").read_text())
    assert est["stations"] == ["BELE", "DGAR"] and est["reference_station"] == "BELE"
    assert est["codes"]["BELE"] == {"L1": "C1C", "L2": "C2W", "L5": "C5X"}
    assert est["codes"]["DGAR"]["L5"] == "C5Q"
    assert len(est["satellites"]) >= 8
    assert "G01" in est["no_orbit"] and "G01" not in est["satellites"]  # G01 flagged unhealthy in BRDC all day
    assert est["admm"]["max_distance_to_centralized_ns"] < 1e-6
    rows = (run_dir / "codebias.csv").read_text().splitlines()
    assert rows[0].startswith("satellite,x_m,x_ns,sigma_ns") and len(rows) == len(est["satellites"]) + 1


def test_agreement_with_cas(run_dir: Path) -> None:
    """Three hours of two stations against CAS: per-satellite differences of about 1 ns (CAS and GFZ themselves
    differ by 0.75 ns RMS on C1W−C2W). The S-basis alignment uses CAS's own BELE receiver DSBs; its mean
    offset is small only if the sign convention (additive receiver + satellite biases) is right — receiver
    DSBs are ~10 ns, so a sign error would show as an offset of several ns."""
    cmp_ = json.loads((run_dir / "comparison.json").read_text())
    assert cmp_["n_common"] >= 8
    assert cmp_["zero_mean"]["rms_ns"] < 2.0
    assert abs(cmp_["s_basis"]["mean_ns"]) < 1.0
    assert cmp_["s_basis"]["rms_ns"] < 2.0
    assert "warning" in cmp_  # DGAR tracks C5Q, BELE C5X


def test_compare_command_gfz_completed_with_cas(
    shared_data: Path, run_dir: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    d = shared_data / IGS
    gfz, cas = d / "GFZ0OPSRAP_20240100000_01D_01D_DCB.BIA.gz", d / "CAS0OPSRAP_20240100000_01D_01D_DCB.BIA.gz"
    rc = main(["gnss", "compare", "--estimates", str(run_dir), "--bias", str(gfz), str(cas), "--out", str(tmp_path)])
    assert rc == 0
    out = json.loads((tmp_path / "comparison.json").read_text())
    chain = next(iter(out["satellites"].values()))["chain"]
    assert chain[:2] == ["CAS C1C-C1W", "GFZ C1W-C2W"] and chain[2] == "CAS C1C-C5X"
    assert out["zero_mean"]["rms_ns"] < 3.0
    assert "RMS" in capsys.readouterr().out


def test_compare_errors(shared_data: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    d = shared_data / IGS
    est = {
        "x_ns": {"G99": 1.0},
        "codes": {"X": {"L1": "C1C", "L2": "C2W", "L5": "C5X"}},
        "reference_station": "X",
        "coefficients": [0.226, -1.226, 1.0],
    }
    with pytest.raises(ModelError, match="no satellite in common"):
        compare_with_products(est, [d / "CAS0OPSRAP_20240100000_01D_01D_DCB.BIA.gz"])
    bad = tmp_path / "codebias.json"
    bad.write_text("{}")
    cas = d / "CAS0OPSRAP_20240100000_01D_01D_DCB.BIA.gz"
    assert main(["gnss", "compare", "--estimates", str(bad), "--bias", str(cas)]) == 2
    assert "not a distnav codebias.json" in capsys.readouterr().err
    assert main(["gnss", "compare", "--estimates", str(tmp_path / "none"), "--bias", "x.bia"]) == 2
    assert "file not found" in capsys.readouterr().err


def test_codebias_command_errors(shared_data: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    nl = shared_data / NL
    nav = str(nl / "cbw10010.21n.gz")
    # a station without L5 code observations
    assert main(["gnss", "codebias", "--obs", str(nl / "delf0010.21o"), "--nav", nav, "--out", str(tmp_path)]) == 2
    assert "no L5 code observation" in capsys.readouterr().err
    # unreadable observation file
    junk = tmp_path / "junk.21o"
    junk.write_text("junk\n")
    assert main(["gnss", "codebias", "--obs", str(junk), "--nav", nav, "--out", str(tmp_path)]) == 2
    assert "junk.21o" in capsys.readouterr().err
    # unknown reference station, malformed --codes
    args = [
        "gnss",
        "codebias",
        "--obs",
        str(nl / "zegv0010.21o"),
        str(nl / "rovn0010.21o"),
        "--nav",
        nav,
        "--out",
        str(tmp_path / "out"),  # not tmp_path: it holds junk.21o, which distnav did not write (issue 29)
        "--no-progress",
    ]
    assert main([*args, "--reference", "XXXX"]) == 2
    assert "not one of the stations" in capsys.readouterr().err
    assert main([*args, "--codes", "L7=C7Q"]) == 2
    assert "--codes expects" in capsys.readouterr().err


def test_small_dutch_network_runs(shared_data: Path, tmp_path: Path) -> None:
    nl = shared_data / NL
    edges = tmp_path / "edges.csv"
    edges.write_text("a,b\nZEGV,ROVN\n")
    rc = main(
        [
            "gnss",
            "codebias",
            "--obs",
            str(nl / "zegv0010.21o"),
            str(nl / "rovn0010.21o"),
            "--nav",
            str(nl / "cbw10010.21n.gz"),
            "--graph",
            str(edges),
            "--out",
            str(tmp_path / "out"),  # not tmp_path: it holds the input edges.csv (issue 29)
            "--no-progress",
            "--iterations",
            "50",
            "--reference",
            "ROVN",
            "--nav-max-age",
            "24",
        ]
    )
    assert rc == 0
    est = json.loads((tmp_path / "out" / "codebias.json").read_text())
    assert est["reference_station"] == "ROVN" and est["graph"]["links"] == [["ROVN", "ZEGV"]]


def test_single_station(shared_data: Path, tmp_path: Path) -> None:
    """One receiver: the S-basis solution is its own undifferenced observable; no network, no ADMM."""
    nl = shared_data / NL
    rc = main(
        [
            "gnss",
            "codebias",
            "--obs",
            str(nl / "zegv0010.21o"),
            "--nav",
            str(nl / "cbw10010.21n.gz"),
            "--out",
            str(tmp_path),
            "--no-progress",
            "--nav-max-age",
            "24",
        ]
    )
    assert rc == 0
    est = json.loads((tmp_path / "codebias.json").read_text())
    assert est["stations"] == ["ZEGV"] and "skipped" in est["admm"]


def test_graph_csv_validation(tmp_path: Path) -> None:
    st = ["BELE", "DGAR", "ZEGV"]
    f = tmp_path / "g.csv"
    f.write_text("# links\nBELE,DGAR\nDGAR00DGA,ZEGV\n")
    g = load_edges(f, st)
    assert g.n_links == 2 and g.is_connected
    f.write_text("BELE,DGAR\nBELE,XXXX\n")
    with pytest.raises(DataFileError, match=r"g\.csv, line 2: unknown station XXXX"):
        load_edges(f, st)
    f.write_text("BELE,DGAR,ZEGV\n")
    with pytest.raises(DataFileError, match="line 1: expected two station names"):
        load_edges(f, st)
    f.write_text("BELE,DGAR\nZEGV,ZEGV\n")
    with pytest.raises(DataFileError, match="line 2: a link from ZEGV to itself"):
        load_edges(f, st)
    f.write_text("BELE,DGAR\n")
    with pytest.raises(Exception, match="not connected"):
        load_edges(f, st)
    with pytest.raises(DataFileError, match="file not found"):
        load_edges(tmp_path / "none.csv", st)


def test_default_graph_is_connected() -> None:
    rng = np.random.default_rng(3)
    pos = rng.normal(size=(7, 3)) * 6.4e6
    g = default_graph(pos, [f"S{i}" for i in range(7)])
    assert g.is_connected and g.n_links >= 6


def test_sp3_and_broadcast_orbits_give_the_same_biases(shared_data: Path, tmp_path: Path) -> None:
    """ESBC 2020-177, one hour: the orbits only set elevations (mask and weights), so precise SP3 and broadcast
    orbits must give the same code biases to far below their σ."""
    d = shared_data / "gnss/esbc_2020177_single_station_L5_sp3"
    common = [
        "gnss",
        "codebias",
        "--obs",
        str(d / "ESBC00DNK_R_20201770000_01D_30S_MO.crx.gz"),
        "--tlim",
        "2020-06-25T00:00",
        "2020-06-25T01:00",
        "--no-progress",
    ]
    assert (
        main(
            [
                *common,
                "--sp3",
                str(d / "GRG0MGXFIN_20201760000_01D_15M_ORB.SP3.gz"),
                str(d / "GRG0MGXFIN_20201770000_01D_15M_ORB.SP3.gz"),
                "--out",
                str(tmp_path / "sp3"),
            ]
        )
        == 0
    )
    assert (
        main(
            [
                *common,
                "--nav",
                str(d / "ESBC00DNK_R_20201770000_01D_MN.rnx.gz"),
                "--nav-max-age",
                "6",
                "--out",
                str(tmp_path / "nav"),
            ]
        )
        == 0
    )
    a = json.loads((tmp_path / "sp3" / "codebias.json").read_text())
    b = json.loads((tmp_path / "nav" / "codebias.json").read_text())
    assert a["codes"]["ESBC"] == {"L1": "C1C", "L2": "C2W", "L5": "C5Q"}
    assert a["satellites"] == b["satellites"] and len(a["satellites"]) >= 4
    for s in a["satellites"]:
        assert abs(a["x_ns"][s] - b["x_ns"][s]) < 0.01 * a["sigma_ns"][s]


def test_default_graph_spanning_tree_is_scipys_ties_included() -> None:
    """default_graph's own Kruskal (issue 32, gnss9: no scipy.sparse import in a run) picks the links scipy's
    minimum_spanning_tree picks, on random stations and on grids and repeated positions where distances tie."""
    from scipy.sparse.csgraph import minimum_spanning_tree

    from distnav.commands.gnss_common import _spanning_tree

    rng = np.random.default_rng(9)
    cases = [rng.normal(0.0, 3e6, (n, 3)) for n in (2, 3, 5, 12, 40) for _ in range(4)]
    cases += [np.array([[x, y, 0.0] for x in range(r) for y in range(c)]) * 1e3 for r, c in ((2, 2), (3, 4), (5, 5))]
    cases += [np.repeat(rng.normal(0.0, 1e6, (4, 3)), 3, axis=0)]  # stations at the same place: 1e-9 weights
    for xyz in cases:
        n = len(xyz)
        w = np.linalg.norm(xyz[:, None] - xyz[None], axis=-1) + 1e-9 * (1 - np.eye(n))
        ref = minimum_spanning_tree(w).tocoo()
        want = {(min(i, j), max(i, j)) for i, j in zip(ref.row.tolist(), ref.col.tolist(), strict=True)}
        got = {(min(i, j), max(i, j)) for i, j in _spanning_tree(w)}
        assert got == want and len(got) == n - 1
    names = [f"S{i}" for i in range(12)]
    graph = default_graph(cases[12], names)
    assert graph.n_nodes == 12
