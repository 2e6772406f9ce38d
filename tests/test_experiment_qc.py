"""`distnav reproduce qc --quick`: distributed data snooping on the code-bias network against the centralized one."""

from __future__ import annotations

import json

import pytest

from distnav.experiments.common import ExperimentContext, Progress
from distnav.experiments.qc import run


@pytest.fixture(scope="module")
def quick_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("qc")
    ctx = ExperimentContext(out_dir=out, quick=True, progress=Progress(enabled=False))
    return out, run(ctx)


def test_distributed_snooping_finds_what_the_centralized_one_finds(quick_run):
    out, res = quick_run
    saved = json.loads((out / "results.json").read_text())
    assert saved["network"]["n_nodes"] == 110 and saved["network"]["observations"] > 300
    d, c = saved["distributed"], saved["centralized"]
    assert saved["same_removals"] and d["removed"] == c["removed"]
    # the claims of the quick run: every injected 6σ error found, no false alarm
    assert d["detected"] == len(saved["injected"]) == 3 and d["false_alarms"] == 0
    assert saved["max_abs_w_difference"] < 1e-6
    assert d["variance_factor"] == pytest.approx(c["variance_factor"], rel=1e-7)
    assert d["redundancy"] == c["redundancy"]
    assert saved["covariance_relative_error_vs_final_centralized"] < 1e-7
    dist = saved["max_distance_to_clean_centralized_m"]
    assert dist["distributed"] == pytest.approx(dist["centralized"], abs=1e-6)
    assert dist["distributed"] < dist["no_snooping"] / 5  # removing the errors brings the solution back
    assert d["extra_iterations"] > 0 and d["extra_messages"] > 0
    assert (out / "fig_qc_snooping.png").stat().st_size > 10_000
    assert saved["headline"] and res["headline"] == saved["headline"]
    # the CKF half (experiments/qc_ckf.py) joins the same results.json and headline
    assert "ckf" in saved and any(k.startswith("CKF: ") for k in saved["headline"])
    assert (out / "ckf_detection.png").stat().st_size > 1000
