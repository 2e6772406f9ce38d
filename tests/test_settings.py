"""distnav._settings: the house style of options objects (resolve_options) and of runners (runs)."""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import FrozenInstanceError, dataclass

import pytest

from distnav._settings import option_names, resolve_options, runs
from distnav.errors import UsageError


@dataclass(frozen=True, kw_only=True)
class _Opts:
    tol: float = 1e-6
    rounds: int = 5

    def __post_init__(self) -> None:
        if self.rounds < 1:
            raise UsageError(f"rounds must be at least 1, got {self.rounds}")


def test_defaults_object_and_changes_combine() -> None:
    assert resolve_options(_Opts, None, {}) == _Opts()
    base = _Opts(tol=1e-3)
    assert resolve_options(_Opts, base, {}) is base
    assert resolve_options(_Opts, base, {"rounds": 9}) == _Opts(tol=1e-3, rounds=9)
    assert option_names(_Opts) == ("tol", "rounds")


def test_unknown_keyword_named_with_nearest() -> None:
    with pytest.raises(UsageError, match=r"no option 'round'.*did you mean 'rounds'"):
        resolve_options(_Opts, None, {"round": 3})


def test_wrong_object_type_and_validation_refused() -> None:
    with pytest.raises(UsageError, match="options must be a _Opts, got dict"):
        resolve_options(_Opts, {"tol": 1.0}, {})  # type: ignore[arg-type]
    with pytest.raises(UsageError, match="rounds must be at least 1, got 0"):
        resolve_options(_Opts, _Opts(), {"rounds": 0})


def test_result_is_frozen() -> None:
    o = resolve_options(_Opts, None, {"tol": 1.0})
    with pytest.raises(FrozenInstanceError):
        o.tol = 2.0  # type: ignore[misc]


def _iterate_steps(x: float, *, rounds: int, exchange: object = None, schedule: object = None) -> Iterator[float]:
    yield from (x / 2**k for k in range(rounds))


def test_runs_accepts_the_iterators_parameters_less_drops_plus_adds() -> None:
    def steps(x: float, *, rounds: int, exchange: object = None, schedule: object = None) -> float:
        return list(_iterate_steps(x, rounds=rounds, exchange=exchange, schedule=schedule))[-1]

    def steps_ref(x: float, *, rounds: int, reference: float = 0.0, exchange: object = None) -> float:
        return list(_iterate_steps(x, rounds=rounds, exchange=exchange))[-1] - reference

    assert runs(_iterate_steps)(steps) is steps  # returned unchanged
    assert runs(_iterate_steps, drops=("schedule",), adds=("reference",))(steps_ref) is steps_ref
    assert steps_ref(8.0, rounds=3, reference=1.0) == 1.0


@pytest.mark.parametrize(
    ("runner_source", "drops", "adds", "message"),
    [
        # a parameter the iterator gained and the runner did not
        (
            "def r(x: float, *, rounds: int, exchange: object = None) -> float: ...",
            (),
            (),
            r"_iterate_steps has "
            r"schedule: object = None, r has none other",
        ),
        # a default changed on one side only
        (
            "def r(x: float, *, rounds: int = 3, exchange: object = None, schedule: object = None) -> float: ...",
            (),
            (),
            r"_iterate_steps has rounds: int, r has rounds: int = 3",
        ),
        # a renamed parameter
        (
            "def r(x: float, *, n_rounds: int, exchange: object = None, schedule: object = None) -> float: ...",
            (),
            (),
            r"_iterate_steps has rounds: int, r has n_rounds: int",
        ),
        # a keyword made positional
        (
            "def r(x: float, rounds: int, *, exchange: object = None, schedule: object = None) -> float: ...",
            (),
            (),
            r"_iterate_steps has rounds: int, r has rounds: int \(positional\)",
        ),
        # the same parameters in another order
        (
            "def r(x: float, *, exchange: object = None, rounds: int, schedule: object = None) -> float: ...",
            (),
            (),
            r"their order differs",
        ),
        # drops / adds that name no parameter
        (
            "def r(x: float, *, rounds: int, exchange: object = None, schedule: object = None) -> float: ...",
            ("shedule",),
            (),
            r"not parameters: shedule",
        ),
        (
            "def r(x: float, *, rounds: int, exchange: object = None, schedule: object = None) -> float: ...",
            (),
            ("reference",),
            r"not parameters: reference",
        ),
    ],
)
def test_runs_refuses_a_runner_that_drifted(
    runner_source: str, drops: tuple[str, ...], adds: tuple[str, ...], message: str
) -> None:
    space: dict[str, object] = {}
    exec(runner_source, space)  # noqa: S102 - a test-local signature, written above
    with pytest.raises(TypeError, match=r"r takes the parameters of _iterate_steps .*" + message):
        runs(_iterate_steps, drops=drops, adds=adds)(space["r"])  # type: ignore[arg-type]
