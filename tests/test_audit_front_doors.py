"""Issue 29 item 2, continued: more public front doors under arguments of every type (property-based, hypothesis).
Each call either returns (and the input was a valid one) or raises a :class:`~distnav.errors.DistnavError` (or, for
the CLI's option types, argparse's ``ArgumentTypeError``, which the CLI prints as ``error: argument --NAME: ...``)
whose message names the argument — never numpy's or Python's own error, never a warning that drops a value.

Front doors in other parts' territory where this audit found a silent or misleading answer are in :data:`FIXED`:
each now ends in an error that names the value (a new finding goes in as ``xfail(strict=True)`` with its owner, the
convention of tests/test_bad_input_audit.py, until the owner's fix lands)."""

from __future__ import annotations

import argparse
import math
import warnings
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from distnav import options
from distnav.errors import DistnavError
from distnav.formats.gnss.product_files import product_day
from distnav.models.gnss.codebias_build import CodeBiasSimulation

SETTINGS = settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow])

#: anything a user may pass where a number is meant
ANY_VALUE = st.one_of(
    st.integers(-5, 5),
    st.sampled_from([2**62, -(2**62)]),
    st.floats(allow_nan=True, allow_infinity=True),
    st.booleans(),
    st.complex_numbers(max_magnitude=10),
    st.text(max_size=4),
    st.none(),
    st.just(np.float64(0.3)),
    st.just(np.int64(2)),
    st.just([0.1, 0.2]),
)


def _is_real(v: object) -> bool:
    return isinstance(v, (int, float, np.integer, np.floating)) and not isinstance(v, (bool, np.bool_))


def _outcome(fn: Callable[[], Any], *clean: type[BaseException]) -> BaseException | None:
    """None when ``fn`` returned; the exception when it raised one of ``clean`` (DistnavError by default) with a
    message; any other exception or a warning fails the test."""
    accepted = clean or (DistnavError,)
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("error")
            fn()
    except accepted as exc:
        assert str(exc).strip(), "an empty message"
        return exc
    return None


@SETTINGS
@given(field=st.sampled_from(["sigma0_m", "mask_rad", "sat_dsb_sigma_ns", "rx_dsb_sigma_ns"]), value=ANY_VALUE)
def test_codebias_simulation_any_number(field: str, value: object) -> None:
    refused = _outcome(lambda: CodeBiasSimulation(**{field: value}))
    if refused is None:
        assert _is_real(value) and math.isfinite(float(value)), f"{field}={value!r} accepted"  # type: ignore[arg-type]
    else:
        assert field in str(refused)


@SETTINGS
@given(value=ANY_VALUE)
def test_codebias_simulation_any_reference(value: object) -> None:
    refused = _outcome(lambda: CodeBiasSimulation(reference=value))  # type: ignore[arg-type]
    if refused is None:
        assert _is_real(value) and float(value).is_integer() and float(value) >= 0  # type: ignore[arg-type]
    else:
        assert "reference" in str(refused)


@SETTINGS
@given(value=st.one_of(ANY_VALUE, st.text(max_size=40), st.builds(Path, st.text(max_size=20))))
def test_product_day_any_name(value: object) -> None:
    refused = _outcome(lambda: product_day(value))  # type: ignore[arg-type]
    if refused is None:
        assert isinstance(value, (str, Path))
    else:
        assert "product_day needs a file name" in str(refused)


def test_product_day_of_a_name_no_file_can_have() -> None:
    """A name with a NUL byte (found by the property test above) is no product of a known day: None, not the bare
    ``ValueError: embedded null byte`` of opening it."""
    assert product_day("\x00") is None
    assert product_day(Path("CAS0OPSRAP_x\x00.BIA")) is None


@pytest.mark.parametrize(
    "parse",
    [
        options.positive_int,
        options.nonnegative_int,
        options.seed,
        options.finite_float,
        options.positive_float,
        options.nonnegative_float,
        options.iso_datetime,
    ],
    ids=lambda f: f.__name__,
)
@SETTINGS
@given(text=st.text(max_size=12) | st.sampled_from(["1e999", "nan", "-inf", "0x10", "1_000", " 7 ", "2**62"]))
def test_option_types_any_text(parse: Callable[[str], Any], text: str) -> None:
    """What the command line gives every option: a value or argparse's error naming the text."""
    refused = _outcome(lambda: parse(text), argparse.ArgumentTypeError)
    if refused is not None:
        assert repr(text) in str(refused) or text.strip() in str(refused) or not text.strip(), str(refused)


# ------------------------------------------------------------------------------------- other parts' front doors
def _admm(**kw: Any) -> Any:
    from distnav.algorithms.lsq.admm import admm
    from distnav.algorithms.lsq.blue import LinearProblem
    from distnav.network import builders

    problem = LinearProblem.from_stacked(np.ones((4, 1, 1)), np.arange(4.0)[:, None])
    return admm(problem, builders.ring(4), **{"W": 1.0, "max_iterations": 5, **kw})


def _graph(n: object) -> Any:
    from distnav.network.graph import Graph

    return Graph.from_links(n, [(0, 1)])  # type: ignore[arg-type]


def _rounds(interval: object, sending: object) -> Any:
    from distnav.algorithms.kalman.ckf import consensus_rounds

    return consensus_rounds(interval, sending)  # type: ignore[arg-type]


def _stacked_complex() -> Any:
    from distnav.algorithms.lsq.blue import LinearProblem, blue

    return blue(LinearProblem.from_stacked(np.ones((4, 1, 1)), np.full((4, 1), 1 + 2j)))


#: (case id, call): found by this audit on the wave's main, each now ending in a DistnavError that names the value
FIXED: list[tuple[str, Callable[[], Any]]] = [
    ("graph-n-nan", lambda: _graph(math.nan)),
    ("graph-n-None", lambda: _graph(None)),
    ("graph-n-2**62", lambda: _graph(2**62)),
    ("from_stacked-complex-y", _stacked_complex),
    ("admm-max_iterations-None", lambda: _admm(max_iterations=None)),
    ("admm-max_iterations-str", lambda: _admm(max_iterations="3")),
    ("admm-tol-complex", lambda: _admm(tol=1 + 2j)),
    ("admm-W-1e300", lambda: _admm(W=1e300)),
    ("consensus_rounds-None", lambda: _rounds(60.0, None)),
    ("consensus_rounds-complex", lambda: _rounds(1 + 2j, 5.0)),
]


@pytest.mark.parametrize("call", [pytest.param(call, id=case) for case, call in FIXED])
def test_fixed_front_doors_refuse_by_name(call: Callable[[], Any]) -> None:
    assert _outcome(call) is not None, "accepted"


# ------------------------------------------------------------------- the GNSS stages' options objects, every field
def _gnss_options_classes() -> list[type]:
    from distnav.commands.gnss_ionosphere_data import NetworkOptions
    from distnav.models.gnss.biasmodel import BiasModelOptions
    from distnav.models.gnss.gfnetwork import BiasFilterOptions
    from distnav.models.gnss.ionogeometry import GeometryOptions
    from distnav.models.gnss.levelling import LevellingOptions
    from distnav.models.gnss.netsim import NetworkSimOptions

    return [BiasModelOptions, BiasFilterOptions, GeometryOptions, LevellingOptions, NetworkSimOptions, NetworkOptions]


def _fits(annotation: str, value: object) -> bool | None:
    """Whether ``value`` has the type the field's annotation names (None: a type this audit does not judge)."""
    if value is None:
        return annotation.endswith("| None")
    kind = annotation.removesuffix(" | None")
    if kind == "int":
        return _is_real(value) and math.isfinite(float(value)) and float(value).is_integer()  # type: ignore[arg-type]
    if kind == "float":
        return _is_real(value) and math.isfinite(float(value))  # type: ignore[arg-type]
    if kind == "bool":
        return isinstance(value, (bool, np.bool_))
    if kind == "str":
        return isinstance(value, str)
    if kind.startswith(("Sequence[", "tuple[")):
        return isinstance(value, (list, tuple, np.ndarray))
    return None


@pytest.mark.parametrize("cls", _gnss_options_classes(), ids=lambda c: c.__name__)
@SETTINGS
@given(data=st.data(), value=st.one_of(ANY_VALUE, st.lists(st.floats(0.1, 5), max_size=3).map(tuple)))
def test_gnss_options_any_field_any_value(cls: type, data: st.DataObject, value: object) -> None:
    """Every field of the GNSS stages' options (int, float, bool, str, sequence) under a value of any type: a
    value of the wrong type is refused by a ModelError naming the field; a value of the right type is kept or
    refused by the class's own range rule (also a DistnavError)."""
    import dataclasses

    field = data.draw(st.sampled_from([f for f in dataclasses.fields(cls) if f.name not in ("model", "field")]))
    fits = _fits(str(field.type), value)
    refused = _outcome(lambda: cls(**{field.name: value}))
    if refused is None:
        assert fits is not False, f"{cls.__name__}({field.name}={value!r}) accepted ({field.type})"
    elif fits is False:
        assert field.name in str(refused), str(refused)


def test_gnss_options_issue_kinds() -> None:
    """The kinds issue 29 names, on the GNSS options: float where int, bool where a number, complex, NaN."""
    from distnav.models.gnss.biasmodel import BiasModelOptions
    from distnav.models.gnss.levelling import LevellingOptions
    from distnav.models.gnss.netsim import NetworkSimOptions

    cases = [
        (lambda: LevellingOptions(min_arc_epochs=2.7), "LevellingOptions.min_arc_epochs must be a whole number"),
        (lambda: LevellingOptions(screen=2.7), "LevellingOptions.screen must be True or False"),
        (lambda: BiasModelOptions(mask_deg=10 + 1j), "BiasModelOptions.mask_deg must be a number"),
        (lambda: BiasModelOptions(band=True), "BiasModelOptions.band must be a whole number, got True"),
        (lambda: NetworkSimOptions(multipath_m=math.nan), "NetworkSimOptions.multipath_m must be a number"),
        (lambda: NetworkSimOptions(station_noise_scale=2.0), "NetworkSimOptions.station_noise_scale must be a list"),
    ]
    for call, words in cases:
        refused = _outcome(call)
        assert refused is not None and words in str(refused), (words, refused)
    assert LevellingOptions(min_arc_epochs=12.0).min_arc_epochs == 12  # a whole float is kept as the int
    assert type(LevellingOptions(min_arc_epochs=np.int64(12)).min_arc_epochs) is int
