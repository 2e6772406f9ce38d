"""``distnav demo --jobs N``: the experiments in N processes give the same results and report as one process."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from distnav.cli import DEMO_SECONDS, main
from distnav.experiments import EXPERIMENTS


def _results(out: Path, name: str) -> str:
    return (out / name / "results.json").read_text(encoding="utf-8")


def test_parallel_demo_same_results_as_sequential(tmp_path: Path, capfd: pytest.CaptureFixture[str]) -> None:
    """Two processes, two experiments: byte-identical results.json, the same figures, both in the report (capfd:
    the workers write to the inherited stderr)."""
    only = ["consensus", "ckf"]
    seq, par = tmp_path / "seq", tmp_path / "par"
    assert main(["demo", "--out", str(seq), "--only", *only, "--jobs", "1"]) == 0
    capfd.readouterr()
    assert main(["demo", "--out", str(par), "--only", *only, "--jobs", "2"]) == 0
    captured = capfd.readouterr()
    for name in only:
        assert _results(seq, name) == _results(par, name), name
        assert sorted(p.name for p in (seq / name).glob("*.png")) == sorted(p.name for p in (par / name).glob("*.png"))
    # progress from the workers as whole lines (no terminal bar), one "done" line per experiment
    for name in only:
        assert f"✓ {name} done" in captured.err
    assert "[1/2] Average consensus" in captured.err and "[2/2] Consensus Kalman" in captured.err
    assert "  … consensus:" in captured.err  # the experiments' own progress lines
    assert "in 2 process(es)" in captured.out
    index = (par / "index.html").read_text(encoding="utf-8")
    for name in only:
        assert f"id='{name}'" in index
        for png in (par / name).glob("*.png"):
            assert f"{name}/{png.name}" in index


def test_parallel_demo_error_is_a_user_error(
    tmp_path: Path, capfd: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    """An experiment option refused in a worker ends the demo with ``error: ...`` and exit code 2, no traceback."""
    from distnav.errors import UsageError
    from distnav.experiments import load

    mod = load("ckf")

    def refuse(ctx: object) -> None:
        raise UsageError("refused in the worker")

    monkeypatch.setattr(mod, "run", refuse)  # the forked worker inherits the patched module
    code = main(["demo", "--out", str(tmp_path / "out"), "--only", "consensus", "ckf", "--jobs", "2", "--no-progress"])
    err = capfd.readouterr().err
    assert code == 2
    assert "error: refused in the worker" in err and "Traceback" not in err
    assert not (tmp_path / "out" / "index.html").exists()


def test_every_experiment_has_a_cost() -> None:
    """The longest-first order knows every experiment (a new one would otherwise start last)."""
    assert set(DEMO_SECONDS) == set(EXPERIMENTS)
    assert json.dumps(DEMO_SECONDS)  # plain numbers


def _square(x: int) -> int:
    return x * x


def _nested_parallel_map(n: int) -> list[int]:
    from distnav.experiments.common import parallel_map

    return parallel_map(_square, list(range(n)), 2)


def test_parallel_map_inside_a_pool_worker_runs_serially() -> None:
    """The demo's workers are daemonic: an experiment's own ``parallel_map`` there must not try to start children
    (it raised "daemonic processes are not allowed to have children" and ended ``make demo`` in a traceback)."""
    import multiprocessing

    with multiprocessing.get_context("fork").Pool(1) as pool:
        assert pool.apply(_nested_parallel_map, (5,)) == [0, 1, 4, 9, 16]
