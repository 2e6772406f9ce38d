"""The ``Examples`` sections of the public front doors' docstrings run as written (doctest) and print what they
say. A front door listed here without an example fails: the list is the promise of issue 25."""

from __future__ import annotations

import doctest
import importlib

import pytest

FRONT_DOORS = [
    ("distnav.exchange.field.survivors", "beyond_reach"),  # who may be alive behind a cut
    ("distnav._settings", "resolve_options"),  # the house style of options objects
    ("distnav._settings", "runs"),  # a runner takes its iterator's parameters
    ("distnav.network.builders", "ring"),
    ("distnav.network.weights", "consensus_weights"),
    ("distnav.network.gather", "gather_cost"),
    ("distnav.exchange", "make_exchange"),
    ("distnav.algorithms.statistics", "critical_value"),
    ("distnav.algorithms.statistics", "variance_factor"),
    ("distnav.algorithms.consensus.averaging", "average_consensus"),  # the algorithm families' front doors
    ("distnav.algorithms.lsq.blue", "blue"),
    ("distnav.algorithms.lsq.admm", "admm"),
    ("distnav.algorithms.kalman.ckf", "ckf"),
    ("distnav.algorithms.consensus.pushsum", "push_sum"),
    ("distnav.algorithms.lsq.qc", "admm_data_snooping"),
    ("distnav.algorithms.lsq.qc", "admm_precision"),
    ("distnav.algorithms.lsq.blue", "method_of_multipliers"),
    ("distnav.algorithms.kalman.information", "central_filter"),
    ("distnav.algorithms.kalman.ckf_design", "ckf_error_variance"),
    ("distnav.models.gnss.biasmodel", "bias_network_model"),  # the GNSS bias pipeline's stages (issue 25 item 4)
    ("distnav.models.gnss.levelling", "level_station"),
    ("distnav.models.gnss.ionogeometry", "ionosphere_geometry"),
    ("distnav.models.gnss.netsim", "simulate_network"),
    ("distnav.models.gnss.systems", "signal_pair_frequencies_hz"),  # per-satellite frequency pairs (issue 32)
    ("distnav.models.gnss.sigmaterms", "channel_ifb_variance_ns2"),  # GLONASS channel biases' share (gnss8)
    ("distnav.algorithms.ranging.csg", "solve_ncsg"),  # the ranging front doors' options objects
]


@pytest.mark.parametrize(("module", "name"), FRONT_DOORS, ids=lambda x: str(x))
def test_front_door_example_runs(module: str, name: str) -> None:
    obj = getattr(importlib.import_module(module), name)
    tests = doctest.DocTestFinder(recurse=False).find(obj, name=f"{module}.{name}", globs={})
    examples = [t for t in tests if t.examples]
    assert examples, f"{module}.{name} has no runnable Examples section"
    runner = doctest.DocTestRunner(optionflags=doctest.ELLIPSIS | doctest.NORMALIZE_WHITESPACE)
    for t in examples:
        runner.run(t)
    result = runner.summarize(verbose=False)
    assert result.failed == 0, f"{result.failed} of {result.attempted} examples of {module}.{name} failed"
