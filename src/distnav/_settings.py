"""The house style of a front door's settings: one frozen options object, validated once, with documented defaults.

Every front door with more than about eight settings takes them as one frozen dataclass (``kw_only``), whose
docstring lists each field with its unit and default and whose ``__post_init__`` checks the values (raising a
:class:`~distnav.errors.DistnavError` that names the field: the family's own, e.g. ``ModelError`` in ranging, else
:class:`~distnav.errors.UsageError`). The front door accepts the object, keyword changes to
it, or both::

    def solve(problem, *, exchange=None, options: SolveOptions | None = None, **changes: Any) -> Result:
        o = resolve_options(SolveOptions, options, changes)

so ``solve(p, rtol=1e-9)`` and ``solve(p, options=SolveOptions(rtol=1e-9))`` run the same. A keyword that is not a
field of the options object is refused by name (with the fields it could have meant), never ignored.

Usable by every layer (it imports only :mod:`distnav.errors` and the standard library).
"""

from __future__ import annotations

import dataclasses
import difflib
from collections.abc import Mapping
from typing import Any, TypeVar

from distnav.errors import UsageError

__all__ = ["option_names", "resolve_options"]

T = TypeVar("T")


def option_names(options_type: type[Any]) -> tuple[str, ...]:
    """The field names of an options dataclass, in their order."""
    return tuple(f.name for f in dataclasses.fields(options_type))


def resolve_options(options_type: type[T], options: T | None, changes: Mapping[str, Any]) -> T:
    """``options`` (or the defaults of ``options_type``) with ``changes`` applied, validated once.

    ``options`` must be an instance of ``options_type`` (or None); every key of ``changes`` must be one of its
    fields, else :class:`~distnav.errors.UsageError` names it and the nearest field. The object's own
    ``__post_init__`` validates the result.

    Examples
    --------
    >>> from dataclasses import dataclass
    >>> from distnav._settings import resolve_options
    >>> @dataclass(frozen=True, kw_only=True)
    ... class StepOptions:
    ...     step_m: float = 1.0
    ...     max_steps: int = 10
    >>> resolve_options(StepOptions, None, {"max_steps": 3})
    StepOptions(step_m=1.0, max_steps=3)
    >>> resolve_options(StepOptions, StepOptions(step_m=0.5), {})
    StepOptions(step_m=0.5, max_steps=10)
    >>> resolve_options(StepOptions, None, {"max_step": 3})
    Traceback (most recent call last):
        ...
    distnav.errors.UsageError: StepOptions has no option 'max_step' (did you mean 'max_steps'?); ...
    """
    if options is not None and not isinstance(options, options_type):
        raise UsageError(f"options must be a {options_type.__name__}, got {type(options).__name__}")
    names = option_names(options_type)
    unknown = [key for key in changes if key not in names]
    if unknown:
        key = unknown[0]
        near = difflib.get_close_matches(key, names, n=1)
        hint = f" (did you mean {near[0]!r}?)" if near else ""
        raise UsageError(f"{options_type.__name__} has no option {key!r}{hint}; its options: {', '.join(names)}")
    if options is None:
        return options_type(**changes)
    if not changes:
        return options
    return dataclasses.replace(options, **changes)  # type: ignore[type-var]
