"""``distnav reproduce-all``: every reproduction in its own process, longest first, with its CPU time."""

from __future__ import annotations

import io
import json
import os

import pytest

from distnav.cli import main
from distnav.commands import reproduce_all
from distnav.commands.reproduce_all import Run, run_all


@pytest.fixture
def src_on_path(monkeypatch):
    """The child processes import this distnav (the tests may run it from a source tree)."""
    import distnav

    src = os.path.dirname(os.path.dirname(distnav.__file__))
    monkeypatch.setenv("PYTHONPATH", os.pathsep.join([src, os.environ.get("PYTHONPATH", "")]))


def test_runs_every_reproduction_and_reports_a_failure(tmp_path, monkeypatch, src_on_path):
    runs = {
        "consensus": Run("consensus", "consensus", cpu_s=1.0),
        "bad": Run("bad", "consensus", ("--no-such-option",), cpu_s=5.0),
    }
    monkeypatch.setattr(reproduce_all, "RUNS", runs)
    echo = io.StringIO()
    summary = run_all(["consensus", "bad"], tmp_path, jobs=1, quick=True, echo=echo)
    started = [line.split(":")[0].strip("… ") for line in echo.getvalue().splitlines() if "…" in line]
    assert started == ["bad", "consensus"]  # the longer one first
    assert summary["failed"] == ["bad"] and summary["runs"]["bad"]["returncode"] == 2
    assert "--no-such-option" in (tmp_path / "bad.log").read_text()
    ok = summary["runs"]["consensus"]
    assert ok["returncode"] == 0 and (tmp_path / "consensus" / "results.json").is_file()
    assert ok["cpu_s"] > 0.5 and ok["cpu_s"] == pytest.approx(ok["cpu_user_s"] + ok["cpu_sys_s"])
    assert summary["cpu_s"] == pytest.approx(ok["cpu_s"] + summary["runs"]["bad"]["cpu_s"])
    assert summary["wall_s"] >= ok["wall_s"] and summary["load_average_1min"]["max"] >= 0
    assert json.loads((tmp_path / "timing.json").read_text())["failed"] == ["bad"]


def test_the_default_set_is_what_the_claims_table_reads_and_options_are_checked(tmp_path, capsys):
    assert set(reproduce_all.RUNS) == {
        "consensus",
        "admm",
        "ckf",
        "uwb",
        "uwb-horizontal",
        "codebias",
        "qc",
        "ckf-ionosphere",
    }
    assert reproduce_all._command(reproduce_all.RUNS["uwb"], tmp_path, 2, False, 0)[2:] == [
        "distnav",
        "reproduce",
        "uwb",
        "--out",
        str(tmp_path / "uwb"),
        "--seed",
        "0",
        "--no-progress",
        "--jobs",
        "2",
    ]
    assert "--jobs" not in reproduce_all._command(reproduce_all.RUNS["ckf"], tmp_path, 2, False, 0)
    with pytest.raises(SystemExit) as exc:
        main(["reproduce-all", "--out", str(tmp_path), "--only", "nonsense"])
    assert exc.value.code == 2


def test_every_reproduction_gets_one_blas_thread_unless_the_user_set_it(tmp_path, monkeypatch, src_on_path):
    monkeypatch.delenv("OPENBLAS_NUM_THREADS", raising=False)
    monkeypatch.delenv("MKL_NUM_THREADS", raising=False)
    monkeypatch.setenv("OMP_NUM_THREADS", "3")
    assert reproduce_all.child_environment({"PATH": "/bin", "MKL_NUM_THREADS": "2"}) == {
        "PATH": "/bin",
        "MKL_NUM_THREADS": "2",
        "OPENBLAS_NUM_THREADS": "1",
        "OMP_NUM_THREADS": "1",
    }
    probe = Run("probe", "consensus", cpu_s=1.0)
    monkeypatch.setattr(reproduce_all, "RUNS", {"probe": probe})
    seen: dict[str, str | None] = {}
    real_popen = reproduce_all.subprocess.Popen

    def spy(cmd, **kw):
        seen.update({k: kw["env"].get(k) for k in reproduce_all.BLAS_THREAD_VARIABLES})
        return real_popen(cmd, **kw)

    monkeypatch.setattr(reproduce_all.subprocess, "Popen", spy)
    summary = run_all(["probe"], tmp_path, jobs=1, quick=True, echo=io.StringIO())
    assert seen == {"OPENBLAS_NUM_THREADS": "1", "OMP_NUM_THREADS": "3", "MKL_NUM_THREADS": "1"}
    assert summary["blas_threads"] == seen and summary["failed"] == []
