"""The CKF half of `reproduce qc` (quick): figures, and the claims its headline makes."""

from __future__ import annotations

import numpy as np
import pytest

from distnav.experiments import qc_ckf
from distnav.experiments.common import ExperimentContext, Progress


@pytest.fixture(scope="module")
def quick_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("qc_ckf")
    ctx = ExperimentContext(out_dir=out, quick=True, seed=0, progress=Progress(enabled=False))
    return out, qc_ckf.run(ctx)


def test_figures_and_headline(quick_run):
    out, r = quick_run
    for name in ("ckf_detection.png", "ckf_distance_trace.png"):
        assert (out / name).stat().st_size > 1000
    assert isinstance(r["headline"], dict) and r["headline"]
    assert not (out / "results.json").exists()  # reproduce qc writes the combined results


def test_claims(quick_run):
    _, r = quick_run
    n_inj = r["setup"]["gross_errors_per_trial"] * r["setup"]["trials"]
    # 8σ errors: the w-test's shift is ≥ 8/sqrt(1 + A P Aᵀ/σ²), far above 3.29 + 1.28 (99 % power at 0.1 %)
    assert r["detection_rate"]["distributed"] >= 1 - 2 / n_inj
    assert r["detection_rate"]["central"] >= 1 - 2 / n_inj
    # false alarms at the 0.1 % level: at most 3× the level in this short run (~1,800 clean observations)
    assert r["false_alarm_rate"]["distributed"] <= 3 * r["setup"]["level"]
    # the tested CKF stays close to the clean CKF, the untested one does not
    d = r["final_distance_to_clean_ckf"]
    assert d["distributed"]["median"] * 3 < d["untested"]["median"]
    c = r["final_distance_to_clean_central"]
    assert c["central"]["median"] < c["distributed"]["median"] < c["untested"]["median"]
    p = r["node_local_precision"]
    assert p["exact_max_ratio"] == pytest.approx(1.0, abs=1e-6) and p["exact_min_ratio"] == pytest.approx(1.0, abs=1e-6)
    assert p["bound_min_ratio"] >= 1 - 1e-9 and np.isfinite(p["bound_max_ratio"])


def test_central_reference_rejects_what_it_should():
    # the central reference on its own: one 30σ error at epoch 3 is the only rejection
    rng = np.random.default_rng(3)
    dyn = qc_ckf._model()
    A, sig = qc_ckf._designs(rng, 6)
    x = np.zeros((6, dyn.n_states))
    y = np.einsum("tnmp,tp->tnm", A, x) + sig * rng.standard_normal(sig.shape)
    y[3, 4, 2] += 30 * sig[3, 4, 2]
    _x, removed = qc_ckf.central_tested_filter(dyn, qc_ckf._epochs(A, sig, y), 1e-4)
    assert removed == {(3, 4, 2)}
