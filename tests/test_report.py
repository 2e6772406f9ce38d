"""The demo report and the claims table: summary, paper values, captions, links that resolve."""

from __future__ import annotations

import importlib
import json
import re
import struct
import zlib
from html.parser import HTMLParser
from pathlib import Path

import pytest

from distnav.experiments import EXPERIMENTS
from distnav.experiments.claims import VERDICTS, claim
from distnav.experiments.claims_table import ADAPTERS, BEGIN, END, claims_for, collect, render, update
from distnav.experiments.report import FIGURE_CAPTIONS, paper_value, split_paper_value, write_report

SRC = Path(__file__).resolve().parents[1] / "src" / "distnav" / "experiments"


class _Links(HTMLParser):
    def __init__(self) -> None:
        super().__init__()
        self.links: list[str] = []
        self.captions = 0
        self.figures = 0

    def handle_starttag(self, tag, attrs):
        a = dict(attrs)
        for key in ("href", "src"):
            if a.get(key):
                self.links.append(a[key])
        self.figures += tag == "figure"
        self.captions += tag == "figcaption"


def assert_links_resolve(out: Path) -> _Links:
    """Every relative href/src of index.html and every link of REPORT.md names an existing file."""
    parser = _Links()
    parser.feed((out / "index.html").read_text(encoding="utf-8"))
    md_links = re.findall(r"\]\(([^)#]+)\)", (out / "REPORT.md").read_text(encoding="utf-8"))
    files = [u for u in parser.links + md_links if not u.startswith(("#", "http:", "https:"))]
    assert files, "the report links no files"
    missing = [u for u in files if not (out / u).is_file()]
    assert not missing, missing
    return parser


def _png(path: Path, width: int, height: int = 10) -> None:
    """A valid tiny PNG of the given size (one grey row repeated)."""
    raw = b"".join(b"\x00" + b"\x80" * width for _ in range(height))

    def chunk(kind: bytes, data: bytes) -> bytes:
        return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data))

    path.write_bytes(
        b"\x89PNG\r\n\x1a\n"
        + chunk(b"IHDR", struct.pack(">IIBBBBB", width, height, 8, 0, 0, 0, 0))
        + chunk(b"IDAT", zlib.compress(raw))
        + chunk(b"IEND", b"")
    )


class _Ctx:
    def __init__(self, figures: list[str]) -> None:
        self.figures = figures


@pytest.mark.parametrize(
    ("label", "expected"),
    [
        ("λ_(n-1) P1 (paper 0.92)", ("λ_(n-1) P1", "0.92")),
        ("hardest class (paper: L)", ("hardest class", "L")),
        ("links / constraint nodes (paper 118 / 9)", ("links / constraint nodes", "118 / 9")),
        ("mean α at the end, RC (paper ≈1.2e-03)", ("mean α at the end, RC", "≈1.2e-03")),
        ("initial ratio (receiver 1; √13 = 3.606)", ("initial ratio (receiver 1; √13 = 3.606)", None)),
    ],
)
def test_split_paper_value(label, expected):
    assert split_paper_value(label) == expected


def test_paper_values_for_labels_without_one():
    assert paper_value("ckf-ionosphere", "central DCB time to 0.5 ns, median [min]") == "38"
    assert paper_value("ckf-ionosphere", "CKF k_n=4 errors within ±3σ (simulated)").startswith("not in the paper")
    assert paper_value("consensus", "something new") == "not stated"


def test_report_summary_captions_paper_column_and_links(tmp_path):
    (tmp_path / "exp").mkdir()
    _png(tmp_path / "exp" / "wide.png", 1300, 400)
    _png(tmp_path / "exp" / "small.png", 1000, 800)
    (tmp_path / "exp" / "results.json").write_text("{}")
    results = {
        "headline": {"λ P1 (paper 0.92)": 0.9175, "a number the paper does not give": 3},
        "claims": [
            claim(
                paper="003",
                where="Fig. 4",
                text="P1 ≈ 80 %",
                paper_value="≈ 0.80",
                distnav_value=0.78,
                ok=True,
                why="w",
                test="t",
            ),
            claim(paper="003", where="Fig. 3", text="x", paper_value=1, distnav_value=2, ok=False, why="w"),
        ],
    }
    index = write_report(tmp_path, [("exp", "An experiment", _Ctx(["wide.png", "small.png"]), results, 1.5)])
    text = index.read_text()
    assert "2 paper claims checked by this run: <b>1 agree</b>, <b>1 differ</b>" in text
    assert "quick variants" in text
    assert "<td>λ P1</td><td>0.9175</td><td>0.92</td>" in text
    assert "<td>a number the paper does not give</td><td>3</td><td>not stated</td>" in text
    assert "<figure class='wide'><a href='exp/wide.png'" in text
    assert "<figure class='half'><a href='exp/small.png'" in text
    parser = assert_links_resolve(tmp_path)
    assert parser.figures == parser.captions == 2
    md = (tmp_path / "REPORT.md").read_text()
    assert "| exp | 003 | Fig. 4 | P1 ≈ 80 % | ≈ 0.80 | 0.78 | agree |" in md


def test_report_link_check_catches_a_missing_figure(tmp_path):
    write_report(tmp_path, [("exp", "E", _Ctx(["gone.png"]), {}, 0.1)])
    with pytest.raises(AssertionError, match="gone.png"):
        assert_links_resolve(tmp_path)


@pytest.mark.parametrize("name", list(EXPERIMENTS))
def test_every_figure_an_experiment_writes_has_a_caption(name):
    stem = EXPERIMENTS[name].rsplit(".", 1)[1]
    # the experiment's module and, where its figures have their own module, <stem>_figures.py
    source = "".join(
        p.read_text(encoding="utf-8") for p in (SRC / f"{stem}.py", SRC / f"{stem}_figures.py") if p.exists()
    )
    figures = set(re.findall(r"\"(\w+\.png)\"", source))
    assert figures, name
    own = getattr(importlib.import_module(EXPERIMENTS[name]), "FIGURE_CAPTIONS", {})
    assert not [f for f in figures if f not in own and f not in FIGURE_CAPTIONS.get(name, {})]


def test_claims_table_adapters_tolerate_missing_fields_and_block_update(tmp_path):
    for name, adapter in ADAPTERS.items():
        rows = [r for r in adapter({}) if "not in results.json" not in r["why"]]  # those not read from a run
        assert rows and {r["verdict"] for r in rows} == {"not checkable"}, name
        assert all("results.json lacks" in r["why"] for r in rows)
    own = [claim(paper="003", where="x", text="y", paper_value=1, distnav_value=1, ok=True)]
    assert claims_for("admm", {"claims": own})[0]["experiment"] == "admm"  # an experiment's own list wins
    (tmp_path / "consensus").mkdir()
    (tmp_path / "consensus" / "results.json").write_text(json.dumps({"claims": own}))
    rows = collect(tmp_path)
    assert len(rows) == 1 and rows[0]["verdict"] in VERDICTS
    doc = "# Claims\n\nintro\n\n" + BEGIN + "\nold table\n" + END + "\n\n## Notes\nkept\n"
    new = update(doc, render(rows, "run"))
    assert new.startswith("# Claims\n\nintro\n\n" + BEGIN) and new.endswith(END + "\n\n## Notes\nkept\n")
    assert "old table" not in new and "1 claims: 1 agree" in new


def test_claims_table_command_rewrites_only_its_block(tmp_path, capsys):
    from distnav.experiments.claims_table import main

    assert main([str(tmp_path / "empty")]) == 2 and "no <experiment>/results.json" in capsys.readouterr().err
    run = tmp_path / "run"
    (run / "consensus").mkdir(parents=True)
    own = [claim(paper="003", where="Fig. 4", text="P4 > P2", paper_value="P4 > P2", distnav_value="yes", ok=True)]
    (run / "consensus" / "results.json").write_text(json.dumps({"claims": own}))
    doc = tmp_path / "claims.md"
    doc.write_text("# Claims\n\n" + BEGIN + "\n" + END + "\n\n## Notes\n")
    assert main([str(run), "--out", str(doc)]) == 0
    text = doc.read_text()
    assert text.startswith("# Claims\n\n" + BEGIN) and text.endswith(END + "\n\n## Notes\n")
    assert "| consensus | 003 | Fig. 4 | P4 > P2 | P4 > P2 | yes | agree |" in text


def test_every_test_the_claims_table_names_exists():
    source = "\n".join(p.read_text(encoding="utf-8") for p in SRC.glob("claims*.py"))  # the table and its adapters
    named = set(re.findall(r"(?<![\w/])test_\w+(?![\w.])", source))  # test functions, not test_*.py files
    tests = "\n".join(p.read_text(encoding="utf-8") for p in (SRC.parents[2] / "tests").glob("test_*.py"))
    defined = set(re.findall(r"^def (test_\w+)", tests, flags=re.M))
    assert named and not named - defined, named - defined
