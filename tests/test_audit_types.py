"""Issue 29 item 2: the public front doors under arguments of every type and shape (property-based, hypothesis):
complex, boolean, string, None, fractional where whole, negative, huge, wrong shapes. Each call either returns (and
then the input was a valid one) or raises a :class:`~distnav.errors.DistnavError` whose message names the argument
— never numpy's or Python's own error (``TypeError``, ``MemoryError``), never a ``ComplexWarning`` with the
imaginary part silently dropped."""

from __future__ import annotations

import math
import warnings

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from distnav.algorithms.consensus.averaging import average_consensus
from distnav.algorithms.lsq.blue import LinearProblem
from distnav.errors import DistnavError
from distnav.network import builders

SETTINGS = settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.too_slow])

#: anything a user may pass where a count is meant; huge values only as fixed examples (a large valid one would be
#: built, which is slow, not wrong)
COUNTS = st.one_of(
    st.integers(-3, 60),
    st.sampled_from([2**31, 2**40, 2**62, 10**30]),
    st.floats(-10, 100),  # a whole float in range is a valid size; a large one would be built (slow, not wrong)
    st.sampled_from([math.nan, math.inf, -math.inf, 2.7, 1e300]),
    st.booleans(),
    st.complex_numbers(max_magnitude=10),
    st.text(max_size=3),
    st.none(),
    st.just(np.int64(7)),
    st.just(np.float64(6.0)),
)


def _is_whole(v: object, minimum: int) -> bool:
    if isinstance(v, (bool, np.bool_)):
        return False
    if isinstance(v, (int, np.integer)):
        return int(v) >= minimum
    return isinstance(v, (float, np.floating)) and math.isfinite(v) and float(v).is_integer() and v >= minimum


def _strict(fn, *args, **kwargs):
    """Call with every warning an error (a ComplexWarning is a silent answer)."""
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        return fn(*args, **kwargs)


def _refused_cleanly(exc: BaseException) -> None:
    assert isinstance(exc, DistnavError), f"{type(exc).__name__}: {exc}"
    assert str(exc).strip(), "an empty message"


@pytest.mark.parametrize(
    ("builder", "minimum"),
    [(builders.ring, 3), (builders.path, 1), (builders.complete, 1), (builders.star, 2), (builders.ladder, 4)],
    ids=["ring", "path", "complete", "star", "ladder"],
)
@SETTINGS
@given(n=COUNTS)
def test_builders_any_count(builder, minimum, n) -> None:
    try:
        graph = _strict(builder, n)
    except Exception as exc:  # noqa: BLE001 - the property: only DistnavError
        _refused_cleanly(exc)
        if _is_whole(n, minimum) and int(n) <= 60 and not (builder is builders.ladder and int(n) % 2):
            pytest.fail(f"{builder.__name__}({n!r}) refused a valid size: {exc}")
        return
    assert _is_whole(n, minimum) and graph.n_nodes == int(n), f"{builder.__name__}({n!r}) accepted"


@SETTINGS
@given(rows=COUNTS, cols=st.integers(-2, 40) | st.floats(0, 5) | st.just(2**40))  # rows up to 100, cols 40
def test_grid_any_shape(rows, cols) -> None:
    try:
        graph = _strict(builders.grid, rows, cols)
    except Exception as exc:  # noqa: BLE001
        _refused_cleanly(exc)
        return
    assert _is_whole(rows, 1) and _is_whole(cols, 1) and graph.n_nodes == int(rows) * int(cols)


DTYPES = st.sampled_from([np.float64, np.int64, np.complex128, np.bool_, np.str_, object, np.float32])
SHAPES = st.sampled_from([(5,), (4,), (6,), (5, 2), (), (5, 0), (0,)])


@st.composite
def arrays(draw):
    dtype, shape = draw(DTYPES), draw(SHAPES)
    base = np.arange(int(np.prod(shape)), dtype=float).reshape(shape) + draw(st.floats(-5, 5))
    if dtype is np.complex128:
        return base + 1j * draw(st.sampled_from([0.0, 0.5]))
    if dtype is np.str_:
        return base.astype(str)
    if dtype is object:
        return base.astype(object)
    return base.astype(dtype)


#: rounds of every type, but no huge whole number (2**62 rounds are a valid request that would run for ever)
ROUNDS = COUNTS.filter(lambda v: not (_is_whole(v, 0) and int(v) > 100))


@SETTINGS
@given(values=arrays(), rounds=ROUNDS)
def test_average_consensus_any_values_and_rounds(values, rounds) -> None:
    graph = builders.ring(5)
    try:
        result = _strict(average_consensus, values, graph=graph, rounds=rounds)
    except Exception as exc:  # noqa: BLE001
        _refused_cleanly(exc)
        return
    assert values.dtype.kind in "iuf" or (values.dtype == object and values.size), values.dtype
    assert values.shape[:1] == (5,) and _is_whole(rounds, 0)
    assert result.estimates.shape == values.shape


@SETTINGS
@given(a=arrays(), y=arrays(), n=st.integers(1, 3))
def test_linear_problem_from_blocks_any_blocks(a, y, n) -> None:
    try:
        problem = _strict(LinearProblem.from_blocks, [a] * n, [y] * n)
    except Exception as exc:  # noqa: BLE001
        _refused_cleanly(exc)
        return
    assert a.ndim == 2 and y.shape == (a.shape[0],) and a.dtype.kind in "iufO" and y.dtype.kind in "iufO"
    assert problem.n_nodes == n


def test_the_issue_examples() -> None:
    """The cases issue 29 names, with the words each message must contain."""
    ring = builders.ring(5)
    cases = [
        (lambda: average_consensus(np.ones(5) + 1j, graph=ring, rounds=3), "complex"),
        (lambda: LinearProblem.from_blocks([np.eye(2) + 1j] * 2, [np.zeros(2)] * 2), "complex"),
        (lambda: LinearProblem.from_blocks([np.eye(2)] * 2, [np.zeros(2) + 1j] * 2), "y_i entries are complex"),
        (lambda: average_consensus(np.ones(5), graph=ring, rounds=2.7), "rounds must be a whole number, got 2.7"),
        (lambda: average_consensus(np.ones(5), graph=ring, rounds=True), "rounds must be a whole number"),
        (lambda: builders.ring(2**40), "GiB of memory"),
        (lambda: builders.grid(2**20, 2**20), "GiB of memory"),
        (lambda: builders.complete(10**6), "links needs at least"),
        (lambda: builders.ring(2.5), "whole number, got 2.5"),
    ]
    for call, words in cases:
        with pytest.raises(DistnavError, match=words):
            _strict(call)
