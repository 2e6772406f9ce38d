"""``distnav field init``: descriptions from a UWB range log and from RINEX station files, checked against
independent readings of the same files (csv module, the header lines read by hand), and bad inputs."""

from __future__ import annotations

import csv
from pathlib import Path

import numpy as np
import pytest

from distnav.cli import main as _main
from distnav.formats.field_config import read_description

pytest.importorskip("tomli_w")


def main(argv: list[str]) -> int:
    """The CLI's exit code, whether the error is found by argparse (SystemExit) or after parsing."""
    try:
        return _main(argv)
    except SystemExit as exc:
        return int(exc.code or 0)


def _links(desc_path: Path) -> set[tuple[int, int]]:
    d = read_description(desc_path)
    return {(min(n.id, j), max(n.id, j)) for n in d.nodes for j in n.neighbours}


def _names(desc_path: Path) -> list[str]:
    lines = [ln for ln in desc_path.read_text().splitlines() if ln.startswith("#   ")]
    return [ln.split("=", 1)[1].strip() for ln in lines]


def test_uwb_from_april_log(shared_data: Path, tmp_path: Path) -> None:
    log = shared_data / "uwb" / "april-dw1000-8node" / "dataset4.txt"
    assert main(["uwb", "import-april", str(log), "--out", str(tmp_path / "april")]) == 0
    ranges = tmp_path / "april" / "ranges.csv"
    out = tmp_path / "net.toml"
    assert main(["field", "init", "--ranges", str(ranges), "--name", "april_dw1000-8.v1", "--out", str(out)]) == 0
    assert read_description(out).name == "april_dw1000-8.v1"  # an identifier-like name is taken as given
    with ranges.open() as f:  # independent reading: every pair with a usable (positive) range
        pairs = {frozenset((r["a"], r["b"])) for r in csv.DictReader(f) if float(r["range_m"]) > 0}
    names = _names(out)
    assert sorted(names, key=int) == sorted({a for p in pairs for a in p}, key=int)
    expected = {tuple(sorted((names.index(a), names.index(b)))) for a, b in map(tuple, pairs)}
    assert _links(out) == expected
    d = read_description(out)
    assert [n.address for n in d.nodes] == [f"tcp://127.0.0.1:{47000 + i}" for i in range(d.n_nodes)]
    assert all(n.data is not None and n.data.resolve() == ranges.resolve() for n in d.nodes)
    # never over an existing file, its own input included
    assert main(["field", "init", "--ranges", str(ranges), "--out", str(out)]) == 2
    assert main(["field", "init", "--ranges", str(ranges), "--out", str(ranges)]) == 2


def _approx_xyz(path: Path) -> np.ndarray:
    for line in path.read_text(errors="replace").splitlines():
        if line[60:].strip() == "APPROX POSITION XYZ":
            return np.array([float(v) for v in line[:42].split()])
    raise AssertionError(f"{path}: no position")


def test_gnss_k_nearest_from_rinex(shared_data: Path, tmp_path: Path) -> None:
    files = sorted((shared_data / "gnss" / "nl_2021001_short_network_snapshot").glob("*.21o"))
    assert len(files) == 4
    out = tmp_path / "gnss.toml"
    rc = main(["field", "init", "--rinex", *map(str, files), "--k", "2", "--hosts", "10.0.0.5", "--out", str(out)])
    assert rc == 0
    pos = np.array([_approx_xyz(f) for f in files])
    dist = np.linalg.norm(pos[:, None] - pos[None], axis=2) + np.diag([np.inf] * 4)
    expected = {tuple(sorted((i, int(j)))) for i in range(4) for j in np.argsort(dist[i])[:2]}
    assert _links(out) == expected
    d = read_description(out)
    assert [n.data for n in d.nodes] == [f.resolve() for f in files]  # stored resolved (../shared may be a link)
    assert {n.address.split(":")[1] for n in d.nodes} == {"//10.0.0.5"}


def test_gnss_nearest_only_splits_the_dutch_stations(shared_data: Path, tmp_path: Path, capsys) -> None:  # type: ignore[no-untyped-def]
    files = sorted((shared_data / "gnss" / "nl_2021001_short_network_snapshot").glob("*.21o"))
    assert main(["field", "init", "--rinex", *map(str, files), "--k", "1", "--out", str(tmp_path / "n.toml")]) == 2
    err = capsys.readouterr().err
    assert "not connected (2 parts" in err and "ROVN, WSRA" in err
    assert not (tmp_path / "n.toml").exists()


def _write_ranges(path: Path, rows: list[tuple[str, str, float]]) -> Path:
    path.write_text("a,b,range_m\n" + "".join(f"{a},{b},{r}\n" for a, b, r in rows))
    return path


def test_disconnected_range_log_names_the_parts(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    ranges = _write_ranges(tmp_path / "r.csv", [("A1", "A2", 3.0), ("A3", "A4", 4.0), ("A2", "A5", 2.0)])
    assert main(["field", "init", "--ranges", str(ranges), "--out", str(tmp_path / "n.toml")]) == 2
    err = capsys.readouterr().err
    assert "not connected" in err and "A1, A2, A5" in err and "A3, A4" in err
    assert not (tmp_path / "n.toml").exists()


@pytest.mark.parametrize(
    ("extra", "match"),
    [
        (["--hosts", "h1,h2"], "2 hosts for 3 nodes"),
        (["--hosts", "bad host!"], "not a host name"),
        (["--base-port", "80"], "1024..65535"),
        (["--base-port", "65534"], "passes port 65535"),
        (["--min-ranges", "2"], "no partner with at least 2"),
        (["--name", "n" * 100_000], "(100,000 characters)"),
        (["--name", "two words"], "1-64 letters, digits"),
        (["--name", "_net"], "starting with a letter or digit"),
        (["--name", "x" * 65], "1-64 letters"),
    ],
)
def test_bad_options_exit_2(tmp_path: Path, capsys: pytest.CaptureFixture[str], extra: list[str], match: str) -> None:
    ranges = _write_ranges(tmp_path / "r.csv", [("1", "2", 3.0), ("2", "3", 4.0), ("1", "2", 3.1)])
    assert main(["field", "init", "--ranges", str(ranges), *extra, "--out", str(tmp_path / "n.toml")]) == 2
    assert match in capsys.readouterr().err
    assert not (tmp_path / "n.toml").exists()


def test_bad_rinex_inputs(shared_data: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    nl = shared_data / "gnss" / "nl_2021001_short_network_snapshot"
    out = str(tmp_path / "n.toml")
    assert main(["field", "init", "--rinex", str(nl / "delf0010.21o"), "--out", out]) == 2
    assert "at least 2 station files" in capsys.readouterr().err
    nav = nl / "AMEL00NLD_R_20210010000_01D_MN.rnx"
    assert main(["field", "init", "--rinex", str(nl / "delf0010.21o"), str(nav), "--out", out]) == 2
    assert "not a RINEX observation file" in capsys.readouterr().err
    twice = [str(nl / "delf0010.21o"), str(nl / "delf0010.21o"), str(nl / "rovn0010.21o")]
    assert main(["field", "init", "--rinex", *twice, "--out", out]) == 2
    assert "stations given twice" in capsys.readouterr().err
    files = [str(nl / f) for f in ("delf0010.21o", "rovn0010.21o", "wsra0010.21o")]
    assert main(["field", "init", "--rinex", *files, "--k", "3", "--out", out]) == 2
    assert "--k must be in 1..2" in capsys.readouterr().err
    junk = tmp_path / "junk.21o"
    junk.write_text("not rinex\n")
    assert main(["field", "init", "--rinex", str(junk), files[0], "--out", out]) == 2
    assert "junk.21o" in capsys.readouterr().err
    assert not (tmp_path / "n.toml").exists()


def test_simulated_network_writes_one_file_per_node_with_only_its_data(tmp_path: Path) -> None:
    from distnav.commands.field_scenarios import codebias_scenario
    from distnav.formats.field_data import read_node_arrays

    out = tmp_path / "cb.toml"
    assert main(["field", "init", "--simulate", "codebias", "--nodes", "6", "--seed", "2", "--out", str(out)]) == 0
    d = read_description(out)
    assert d.algorithm["name"] == "admm" and d.n_nodes == 6
    problem = codebias_scenario(6, 2).problem  # the same simulation, built here independently of the files
    assert problem is not None
    for n in d.nodes:
        assert n.data is not None and n.data.parent == tmp_path / "data-cb"
        a = read_node_arrays(n.data, "admm", n.id, 6)
        assert np.array_equal(a["A"], problem.A[n.id]) and np.array_equal(a["y"], problem.y[n.id])
        assert a["A"].shape == problem.A.shape[1:]  # one node's block, not the network's
    # never over existing data files, and bad counts refused before any work
    assert main(["field", "init", "--simulate", "codebias", "--out", str(tmp_path / "cb2.toml")]) == 0
    (tmp_path / "cb3.toml").write_text("")
    assert main(["field", "init", "--simulate", "ckf", "--out", str(tmp_path / "cb3.toml")]) == 2
    (tmp_path / "data-cb4").mkdir()
    assert main(["field", "init", "--simulate", "ckf", "--out", str(tmp_path / "cb4.toml")]) == 2
    assert main(["field", "init", "--simulate", "hall", "--nodes", "3", "--out", str(tmp_path / "h.toml")]) == 2


def test_a_byte_order_mark_reads_as_without_it(tmp_path: Path) -> None:
    """A description or a node's number file saved by a Windows editor starts with a UTF-8 byte-order mark; it reads
    as the same file without it (it was "not valid TOML (Invalid statement at line 1, column 1)")."""
    from distnav.formats.field_config import read_node_values

    ranges = _write_ranges(tmp_path / "r.csv", [("A1", "A2", 3.0), ("A2", "A3", 4.0), ("A1", "A3", 2.0)])
    plain = tmp_path / "n.toml"
    assert main(["field", "init", "--ranges", str(ranges), "--out", str(plain)]) == 0
    marked = tmp_path / "bom.toml"
    marked.write_bytes(b"\xef\xbb\xbf" + plain.read_bytes())
    assert read_description(marked).nodes == read_description(plain).nodes
    numbers = tmp_path / "values.txt"
    numbers.write_bytes(b"\xef\xbb\xbf1.5 2.5\n")
    np.testing.assert_array_equal(read_node_values(numbers, 0), [1.5, 2.5])
