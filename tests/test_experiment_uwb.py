"""The paper 002 reproduction (``distnav reproduce uwb``) on a tiny setting: files, table structure, accounting."""

from __future__ import annotations

import json

import numpy as np
import pytest

from distnav.algorithms.ranging.csg import SOLVERS
from distnav.cli import main
from distnav.experiments import uwb
from distnav.experiments.common import ExperimentContext, Progress
from distnav.models.uwb.problems import PAPER_PROBLEMS, generate_layout


@pytest.fixture(scope="module")
def results(tmp_path_factory):
    out = tmp_path_factory.mktemp("uwb")
    ctx = ExperimentContext(
        out_dir=out, quick=True, progress=Progress(enabled=False), options={"instances": 1, "iterations": 12}
    )
    return out, uwb.run(ctx)


def test_files_and_table_shape(results):
    out, res = results
    for name in (
        "results.json",
        "table.csv",
        "table.md",
        "fig3_rmse.png",
        "fig4_cost.png",
        "fig5_examples.png",
        "fig6_step_size.png",
    ):
        assert (out / name).stat().st_size > 0, name
    on_disk = json.loads((out / "results.json").read_text())
    rows = on_disk["table"]
    assert {(r["problem"], r["solver"]) for r in rows} == {(p, s) for p in PAPER_PROBLEMS for s in SOLVERS}
    for r in rows:
        assert isinstance(r["messages"], int) and isinstance(r["bytes"], int)
        assert r["rmse_m"] is None or isinstance(r["rmse_m"], float)
        assert r["iterations"] == 12 and r["instances"] == 1
    assert on_disk["headline"] and "hardest class, N-CSG-BLS/TBLS (paper: L)" in on_disk["headline"]
    assert on_disk["checks"]["hardest_class_line_search"] in ("G", "L", "R")
    csv_lines = (out / "table.csv").read_text().splitlines()
    assert len(csv_lines) == 1 + len(PAPER_PROBLEMS) * len(SOLVERS)
    assert "| GC |" in (out / "table.md").read_text()


def test_curves_start_at_the_initial_guess(results):
    _, res = results
    for p in PAPER_PROBLEMS:
        first = {s: res["curves"][p][s]["rmse_m"][0] for s in SOLVERS}
        row = {r["solver"]: r for r in res["table"] if r["problem"] == p}
        kept = [v for s, v in first.items() if not row[s]["diverged"]]  # a blown-up run is left out (NaN)
        assert len(set(np.round(kept, 12))) == 1  # every solver starts from the same guess
        assert 4.3 < first["LM"] < 5.7  # U(−5, 5) per coordinate: E‖e‖² = 3 · 10²/12 = 25 m², RMSE ≈ 5 m
        assert len(res["curves"][p]["N-CSG-TBLS"]["step_size"]) == 13


def test_message_accounting(results):
    _, res = results
    g_links = generate_layout("G")[1].shape[0]
    row = {(r["problem"], r["solver"]): r for r in res["table"]}
    assert row[("GC", "LM")]["messages"] == 0
    for s in SOLVERS[1:]:
        assert row[("GC", s)]["messages"] == 12 * 2 * g_links  # one message per directed edge and iteration
    csg = row[("GC", "CSG")]["bytes"] / row[("GC", "CSG")]["messages"]
    ncsg = row[("GC", "N-CSG")]["bytes"] / row[("GC", "N-CSG")]["messages"]
    assert csg == 100 * 3 * 8 and ncsg == (8 + 1) * 3 * 8  # whole network vs max degree + 1
    # issue 27: instance 0 of the example problems beside gathering every range (16 B) at one anchor
    vs = res["communication_vs_gather"]
    assert set(vs) == {f"{p}, {s}, instance 0" for p in ("GO", "LC", "RM") for s in ("N-CLM", "N-CSG-TBLS")}
    for v in vs.values():
        assert v["gather"]["unreachable_nodes"] == 0 and v["gather"]["data_bytes"] % 16 == 0
        assert v["distributed"]["messages"] > 0
        assert v["ratio_bytes"] == pytest.approx(v["distributed"]["bytes"] / v["gather"]["total_hop_bytes"])


def test_cli_registration_and_bad_instances(tmp_path, capsys):
    with pytest.raises(SystemExit):
        main(["reproduce", "uwb", "--help"])
    assert "--instances" in capsys.readouterr().out
    ctx = ExperimentContext(out_dir=tmp_path, quick=True, progress=Progress(enabled=False), options={"instances": 0})
    with pytest.raises(ValueError, match="instances"):
        uwb.run(ctx)


def test_worker_processes_give_the_serial_results(results, tmp_path):
    """``--jobs 1`` (no worker processes) and the default (the fixture: one worker per core, 2 here) agree
    exactly: every instance seeds its own draws and the means are summed in instance order."""
    _, res = results
    ctx = ExperimentContext(
        out_dir=tmp_path,
        quick=True,
        progress=Progress(enabled=False),
        options={"instances": 1, "iterations": 12, "jobs": 1},
    )
    serial = uwb.run(ctx)
    strip = lambda r: json.dumps(
        {k: v for k, v in r.items() if k != "solver_seconds"},
        sort_keys=True,  # noqa: E731
        default=lambda a: np.asarray(a).tolist(),
    )
    assert strip(serial) == strip(res)


def test_horizontal_start_is_the_default_draw_with_true_heights():
    rng = lambda: np.random.default_rng([0, 1001])  # noqa: E731
    paper = uwb.instance_problem("GC", rng())
    flat = uwb.instance_problem("GC", rng(), start="horizontal")
    assert np.array_equal(flat.initial_m[:, :2], paper.initial_m[:, :2])  # same horizontal perturbation
    assert np.array_equal(flat.initial_m[:, 2], flat.truth_m[:, 2])  # heights start at the truth (z = 0)
    assert np.abs(paper.initial_m[paper.estimated, 2]).max() > 4  # the paper's start: U(−5, 5) m in z too
    assert np.array_equal(flat.range_m, paper.range_m)
    with pytest.raises(ValueError, match="--start"):
        uwb.instance_problem("GC", rng(), start="vertical")


@pytest.mark.parametrize(("name", "bound_m"), [("GC", 0.6), ("LC", 1.0), ("RC", 0.6)])
def test_sixty_centimetres_only_from_a_horizontal_start(name, bound_m):
    """Paper 002 §5: distributed RMSE "generally below 60 cm". From the paper's start (heights off by up to ±5 m)
    a planar truth is a saddle point of the 3-D cost and N-CSG-BLS ends with metres of error; perturbed
    horizontally only, the same first instance ends below 0.6 m on GC and RC and at 0.81 m on LC (the means over
    5 instances: G 0.33, R 0.70, L 0.77 m; docs/uwb.md, docs/claims.md)."""
    from distnav.algorithms.ranging.csg import PAPER_MODE, solve

    rng = lambda: np.random.default_rng([0, 1000 * (PAPER_PROBLEMS.index(name) + 1)])  # noqa: E731
    final = {}
    for start in uwb.STARTS:
        p = uwb.instance_problem(name, rng(), start=start)
        final[start] = float(solve(p, "N-CSG-BLS", iterations=500, **PAPER_MODE).trace["rmse_m"][-1])
    assert final["paper"] > 1.0 and final["horizontal"] < bound_m, final


@pytest.fixture(scope="module")
def first_instances():
    """LM and N-CSG-BLS (= TBLS, tests/test_claims.py) on the first instance of GC, LC and RC, the paper's 500
    iterations and start: the reproduction's own draws (seed 0)."""
    from distnav.algorithms.ranging.csg import PAPER_MODE, solve

    out = {}
    for name in ("GC", "LC", "RC"):
        p = uwb.instance_problem(name, np.random.default_rng([0, 1000 * (PAPER_PROBLEMS.index(name) + 1)]))
        lm = solve(p, "LM", iterations=500, pad_trace=True)
        bls = solve(p, "N-CSG-BLS", iterations=500, **PAPER_MODE)
        out[name] = {"lm": lm, "bls": bls, "m": p.n_meas}
    return out


def test_lm_has_the_lowest_cost_and_the_distributed_solver_the_lower_rmse(first_instances):
    """Table 1: LM reaches the lowest cost, yet N-CSG-BLS/TBLS the lower RMSE (the cost is nearly flat in the
    heights of a planar network, and LM's lower cost does not buy a better position)."""
    for name, r in first_instances.items():
        assert r["lm"].cost < r["bls"].cost, name
        assert r["bls"].trace["rmse_m"][-1] < r["lm"].trace["rmse_m"][-1], name


def test_line_search_step_rises_to_the_papers_value(first_instances):
    """Fig. 6: the mean BLS/TBLS α on class R rises from 1e-3-ish to ≈ 1.2e-3 by iteration 500 (paper: 1.2e-3 /
    1.3e-3; distnav's BLS and TBLS take identical steps)."""
    step = np.asarray(first_instances["RC"]["bls"].trace["step_size"])
    assert abs(step[-1] - 1.2e-3) < 0.15e-3, step[-1]
    assert step[-1] > step[50]  # rises over the run
