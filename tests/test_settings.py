"""distnav._settings: the house style of options objects (resolve_options)."""

from __future__ import annotations

from dataclasses import FrozenInstanceError, dataclass

import pytest

from distnav._settings import option_names, resolve_options
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
