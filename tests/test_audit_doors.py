"""Issue 29 item 2, the rest of the public front doors (property-based, hypothesis): consensus (push-sum, the
consensus product), least squares (BLUE, ADMM, the method of multipliers), Kalman (the models, the filters, the
CKF), ranging (``solve``), the network's weights and gather cost, the exchange factory and its faults, and the UWB
problem builders (layouts, paper problems, the simulated hall).

Each front door's argument gets values of every type (:data:`~test_audit_front_doors.ANY_VALUE`: whole and
fractional numbers, NaN, ±inf, huge, bool, complex, text, None, numpy scalars, a list). The call either returns —
and then the value had the argument's type — or raises a :class:`~distnav.errors.DistnavError`; when the value had
the wrong type, the message names the argument. Never Python's or numpy's own error, never a warning (a
``ComplexWarning`` is an imaginary part silently dropped), never a wrong type used silently (``n_fixed=2.7``
fixing every anchor)."""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from test_audit_front_doors import ANY_VALUE, _is_real, _outcome

SETTINGS = settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.too_slow])


@dataclass(frozen=True)
class Door:
    """One argument of one front door: ``call(value)`` runs the door with ``value`` in that argument.

    ``kind``: ``"whole"`` (an integer count or index), ``"real"`` (a finite real number) or None (a name or an
    array: refused cleanly, never judged by type). ``optional``: None is a valid value. ``long``: a huge whole
    number is a valid request that would run for ever (an iteration count), so huge values are not drawn."""

    id: str
    arg: str
    kind: str | None
    call: Callable[[object], Any]
    optional: bool = False
    long: bool = False


def _fits(door: Door, value: object) -> bool | None:
    if value is None:
        return door.optional
    if door.kind is None:
        return None
    finite = _is_real(value) and math.isfinite(float(value))  # type: ignore[arg-type]
    if door.kind == "whole":
        return finite and float(value).is_integer()  # type: ignore[arg-type]
    return finite


def _doors() -> list[Door]:
    from distnav.algorithms.consensus.averaging import average_consensus, consensus_product
    from distnav.algorithms.consensus.pushsum import push_sum
    from distnav.algorithms.kalman import DynamicModel, ObservationSeries, kalman_filter
    from distnav.algorithms.kalman.ckf import ckf
    from distnav.algorithms.lsq.admm import admm
    from distnav.algorithms.lsq.blue import LinearProblem, blue, method_of_multipliers
    from distnav.algorithms.ranging.csg import solve
    from distnav.exchange import FaultSchedule, make_exchange
    from distnav.models.uwb.hall import simulate_hall
    from distnav.models.uwb.problems import build_problem, generate_layout, generate_problem, select_fixed
    from distnav.network import builders, consensus_weights
    from distnav.network.gather import gather_cost
    from distnav.network.weights import protocol_weights

    ring4, ring5 = builders.ring(4), builders.ring(5)
    lsq = LinearProblem.from_stacked(np.ones((4, 1, 1)), np.arange(4.0)[:, None])
    one = DynamicModel(1)
    obs = ObservationSeries(1, [[(np.ones((1, 1)), np.eye(1), np.array([float(i)])) for i in range(4)]] * 3)
    uwb = generate_problem("GC", np.random.default_rng(0), n_anchors=16)
    corner = np.random.default_rng(0).random((16, 2))
    rng = np.random.default_rng

    def tri(range_m: object) -> Any:
        fixed = {"a": [0.0, 0.0], "b": [1.0, 0.0], "c": [0.0, 1.0]}
        return build_problem(["a", "b", "c", "d"], [(0, 3), (1, 3), (2, 3)], range_m, fixed=fixed, dim=2)  # type: ignore[arg-type]

    return [
        Door(
            "average_consensus-protocol",
            "protocol",
            None,
            lambda v: average_consensus(np.ones(5), graph=ring5, rounds=2, protocol=v),
        ),  # type: ignore[arg-type]
        Door("push_sum-ticks", "ticks", "whole", lambda v: push_sum(np.arange(5.0), graph=ring5, ticks=v)),  # type: ignore[arg-type]
        Door("push_sum-tol", "tol", "real", lambda v: push_sum(np.arange(5.0), graph=ring5, ticks=5, tol=v)),  # type: ignore[arg-type]
        Door(
            "consensus_product-rounds",
            "rounds",
            "whole",
            lambda v: consensus_product(consensus_weights(ring5, "P3"), v),
            long=True,
        ),  # type: ignore[arg-type]
        Door("consensus_weights-protocol", "protocol", None, lambda v: consensus_weights(ring5, v)),  # type: ignore[arg-type]
        Door("protocol_weights-protocol", "protocol", "whole", lambda v: protocol_weights(ring5, v)),  # type: ignore[arg-type]
        Door("gather_cost-sink", "sink", "whole", lambda v: gather_cost(ring5, [100] * 5, sink=v), optional=True),  # type: ignore[arg-type]
        Door("gather_cost-bytes", "bytes_per_node", None, lambda v: gather_cost(ring5, v)),  # type: ignore[arg-type]
        Door("make_exchange-backend", "backend", None, lambda v: make_exchange(ring5, backend=v)),  # type: ignore[arg-type]
        Door("make_exchange-order", "order", None, lambda v: make_exchange(ring5, order=v)),
        Door("FaultSchedule-drop_probability", "drop_probability", "real", lambda v: FaultSchedule(drop_probability=v)),  # type: ignore[arg-type]
        Door("FaultSchedule-seed", "seed", "whole", lambda v: FaultSchedule(seed=v)),  # type: ignore[arg-type]
        Door("admm-atol", "atol", "real", lambda v: admm(lsq, ring4, W=1.0, max_iterations=5, atol=v)),  # type: ignore[arg-type]
        Door(
            "admm-stop_at_reference",
            "stop_at_reference",
            "real",
            lambda v: admm(lsq, ring4, W=1.0, max_iterations=5, stop_at_reference=v, reference=np.ones(1)),
            optional=True,
        ),  # type: ignore[arg-type]
        Door("blue-rcond", "rcond", "real", lambda v: blue(lsq, rcond=v)),  # type: ignore[arg-type]
        Door("blue-W", "W", "real", lambda v: blue(lsq, W=v), optional=True),  # type: ignore[arg-type]
        Door(
            "method_of_multipliers-iterations",
            "iterations",
            "whole",
            lambda v: method_of_multipliers(lsq, W=1.0, iterations=v),
            long=True,
        ),  # type: ignore[arg-type]
        Door("method_of_multipliers-W", "W", "real", lambda v: method_of_multipliers(lsq, W=v, iterations=3)),  # type: ignore[arg-type]
        Door("DynamicModel-n_states", "n_states", "whole", lambda v: DynamicModel(v)),  # type: ignore[arg-type]
        Door(
            "ObservationSeries-n_states",
            "n_states",
            "whole",
            lambda v: ObservationSeries(v, [[(np.ones((1, 1)), np.eye(1), np.zeros(1))]]),
        ),  # type: ignore[arg-type]
        Door(
            "kalman_filter-max_batch_epochs",
            "max_batch_epochs",
            "whole",
            lambda v: kalman_filter(one, obs, max_batch_epochs=v),
        ),  # type: ignore[arg-type]
        Door("ckf-rounds", "rounds", "whole", lambda v: ckf(one, obs, graph=ring4, rounds=v), long=True),  # type: ignore[arg-type]
        Door(
            "ckf-test_level",
            "test_level",
            "real",
            lambda v: ckf(one, obs, graph=ring4, rounds=2, test_level=v),
            optional=True,
        ),  # type: ignore[arg-type]
        Door("generate_layout-n_anchors", "n_anchors", "whole", lambda v: generate_layout("G", rng(0), n_anchors=v)),  # type: ignore[arg-type]
        Door(
            "generate_layout-spacing_m",
            "spacing_m",
            "real",
            lambda v: generate_layout("G", rng(0), n_anchors=16, spacing_m=v),
        ),  # type: ignore[arg-type]
        Door(
            "generate_layout-range_limit_m",
            "range_limit_m",
            "real",
            lambda v: generate_layout("R", rng(0), n_anchors=16, range_limit_m=v),
        ),  # type: ignore[arg-type]
        Door(
            "generate_layout-max_tries",
            "max_tries",
            "whole",
            lambda v: generate_layout("R", rng(0), n_anchors=16, max_tries=v),
        ),  # type: ignore[arg-type]
        Door(
            "generate_problem-n_fixed",
            "n_fixed",
            "whole",
            lambda v: generate_problem("GC", rng(0), n_anchors=16, n_fixed=v),
        ),  # type: ignore[arg-type]
        Door(
            "generate_problem-sigma_m",
            "sigma_m",
            "real",
            lambda v: generate_problem("GC", rng(0), n_anchors=16, sigma_m=v),
        ),  # type: ignore[arg-type]
        Door(
            "generate_problem-init_halfwidth_m",
            "init_halfwidth_m",
            "real",
            lambda v: generate_problem("GC", rng(0), n_anchors=16, init_halfwidth_m=v),
        ),  # type: ignore[arg-type]
        Door("generate_problem-dim", "dim", "whole", lambda v: generate_problem("GC", rng(0), n_anchors=16, dim=v)),  # type: ignore[arg-type]
        Door("select_fixed-n_fixed", "n_fixed", "whole", lambda v: select_fixed(corner, "C", v)),  # type: ignore[arg-type]
        Door("build_problem-range_m", "range_m", None, tri),
        Door("simulate_hall-n_anchors", "n_anchors", "whole", lambda v: simulate_hall(rng(0), n_anchors=v, n_known=2)),
        Door(
            "simulate_hall-sigma_m",
            "sigma_m",
            "real",
            lambda v: simulate_hall(rng(0), n_anchors=6, n_known=3, sigma_m=v),
        ),
        Door("solve-iterations", "iterations", "whole", lambda v: solve(uwb, "CSG", iterations=v), long=True),  # type: ignore[arg-type]
        Door("solve-LM-iterations", "iterations", "whole", lambda v: solve(uwb, "LM", iterations=v), long=True),  # type: ignore[arg-type]
        Door(
            "solve-consensus_rounds",
            "consensus_rounds",
            "whole",
            lambda v: solve(uwb, "CSG", iterations=3, consensus_rounds=v),
            long=True,
        ),
        Door("solve-test_level", "test_level", "real", lambda v: solve(uwb, "LM", iterations=5, test_level=v)),
    ]


DOORS = _doors()
#: values of every type, numbers up to 100 in size: a large whole number that fits in memory is a valid size or
#: count (10⁸ anchors, 10⁸ iterations) that would run for minutes, not a bad input
SHORT = ANY_VALUE.filter(lambda v: not (_is_real(v) and abs(float(v)) > 100))  # type: ignore[arg-type]
#: plus the huge ones that no machine holds (refused before numpy allocates), where a huge count is not endless
HUGE = st.one_of(SHORT, st.sampled_from([2**62, -(2**62), 1e300]))


def _names(arg: str) -> tuple[str, ...]:
    """How a message may name the argument: as written, or in words (``test_level``: "test level")."""
    return (arg, arg.replace("_", " "))


@pytest.mark.parametrize("door", DOORS, ids=lambda d: d.id)
@SETTINGS
@given(data=st.data())
def test_front_door_any_value(door: Door, data: st.DataObject) -> None:
    value = data.draw(SHORT if door.long else HUGE, label=door.arg)
    fits = _fits(door, value)
    refused = _outcome(lambda: door.call(value))
    if refused is None:
        assert fits is not False, f"{door.id}: {door.arg}={value!r} accepted"
    elif fits is False:
        assert any(name in str(refused) for name in _names(door.arg)), f"{door.id}: {refused}"


def test_every_named_front_door_has_a_case() -> None:
    """The brief's list: consensus, lsq, kalman, ranging, network builders/weights, gather, exchange factory,
    GNSS stages' options (tests/test_audit_front_doors.py), UWB problem builders."""
    covered = {d.id.split("-")[0] for d in DOORS}
    assert {"average_consensus", "push_sum", "consensus_product", "consensus_weights", "protocol_weights"} <= covered
    assert {"admm", "blue", "method_of_multipliers", "DynamicModel", "kalman_filter", "ckf", "solve"} <= covered
    assert {"gather_cost", "make_exchange", "FaultSchedule"} <= covered
    assert {"generate_layout", "generate_problem", "select_fixed", "build_problem", "simulate_hall"} <= covered


def test_the_findings_by_name() -> None:
    """What this audit found on the wave's main (a traceback, or a wrong type used silently), each now an error
    naming the argument."""
    by_id = {d.id: d for d in DOORS}
    cases = [
        ("push_sum-ticks", 2.7, "ticks must be a whole number, got 2.7"),
        ("generate_problem-n_fixed", 2.7, "n_fixed must be a whole number, got 2.7"),  # before: every anchor fixed
        ("select_fixed-n_fixed", None, "n_fixed must be a whole number, got None"),
        ("generate_problem-dim", 0, "dim must be 2 or 3, got 0"),
        ("blue-W", "3", "the weight W must be numbers"),  # before: the text '3' taken as ρ = 3
        ("blue-rcond", None, "rcond must be a number"),
        ("DynamicModel-n_states", 2.7, "n_states must be a whole number"),  # before: truncated to 2
        ("DynamicModel-n_states", 2**40, "GiB of memory"),
        ("ckf-rounds", math.nan, "rounds must be a whole number"),
        ("ckf-test_level", 1 + 2j, "test_level must be a number"),
        ("make_exchange-order", math.nan, "order must be 'auto'"),
        ("FaultSchedule-seed", "3", "FaultSchedule.seed must be a whole number"),
        ("generate_layout-n_anchors", -1, "n_anchors must be ≥ 1"),  # before: numpy's sqrt warning
        ("simulate_hall-n_anchors", 2**62, "GiB of memory"),  # before: numpy tried 22.6 GiB
        ("simulate_hall-sigma_m", -1.0, "HallConfig.sigma_m must be ≥ 0"),
        ("solve-iterations", 2.7, "iterations must be a whole number, got 2.7"),
        ("solve-consensus_rounds", 2.5, "consensus_rounds must be a whole number"),
        ("admm-stop_at_reference", "1e-6", "stop_at_reference must be a number"),
        ("gather_cost-sink", math.inf, "sink must be a whole number"),
    ]
    for door_id, value, words in cases:
        refused = _outcome(lambda: by_id[door_id].call(value))  # noqa: B023 - called at once
        assert refused is not None and words in str(refused), (door_id, value, refused)
