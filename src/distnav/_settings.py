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

A front door that runs an ``iterate_…`` generator to the end takes the generator's parameters, spelled out (its
body and its docs use them by name), and says so with :func:`runs`, which checks the two lists once, at import.

Usable by every layer (it imports only :mod:`distnav.errors` and the standard library).
"""

from __future__ import annotations

import dataclasses
import difflib
import inspect
from collections.abc import Callable, Iterator, Mapping
from typing import Any, TypeVar

from distnav.errors import UsageError

__all__ = ["option_names", "resolve_options", "runs"]

T = TypeVar("T")
F = TypeVar("F", bound=Callable[..., Any])


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


def runs(
    iterator: Callable[..., Iterator[Any]], *, adds: tuple[str, ...] = (), drops: tuple[str, ...] = ()
) -> Callable[[F], F]:
    """Declare the decorated front door the runner of ``iterator``: it takes the iterator's parameters (the same
    names, kinds, defaults and annotations, in the same order), less ``drops`` (what the runner decides itself, e.g.
    the schedule) and plus ``adds`` (its result's own settings, e.g. ``reference``). Checked once, when the module is
    imported: a parameter added to, renamed in or dropped from one of the two and not the other is a ``TypeError``
    naming both functions and the parameter, so the two signatures cannot drift apart. The runner is returned
    unchanged (its own signature, typed by mypy, is what callers see).

    Examples
    --------
    >>> from collections.abc import Iterator
    >>> from distnav._settings import runs
    >>> def iterate_halving(x: float, *, steps: int = 3) -> Iterator[float]:
    ...     for _ in range(steps):
    ...         x /= 2
    ...         yield x
    >>> @runs(iterate_halving)
    ... def halving(x: float, *, steps: int = 3) -> float:
    ...     return list(iterate_halving(x, steps=steps))[-1]
    >>> halving(8.0)
    1.0
    >>> @runs(iterate_halving)
    ... def halving(x: float, *, steps: int = 4) -> float:
    ...     return list(iterate_halving(x, steps=steps))[-1]
    Traceback (most recent call last):
        ...
    TypeError: halving takes the parameters of iterate_halving ...: ... has steps: int = 3, halving has steps: int = 4
    """

    def check(runner: F) -> F:
        theirs = inspect.signature(iterator).parameters
        ours = inspect.signature(runner).parameters
        stray = [name for name in drops if name not in theirs] + [name for name in adds if name not in ours]
        want = [_parameter(q) for name, q in theirs.items() if name not in drops]
        have = [_parameter(q) for name, q in ours.items() if name not in adds]
        if want != have or stray:
            only_it = [_show(q) for q in want if q not in have]
            only_run = [_show(q) for q in have if q not in want]
            raise TypeError(
                f"{runner.__name__} takes the parameters of {iterator.__name__} (less drops, plus adds): "
                f"{iterator.__name__} has {', '.join(only_it) or 'none other'}, {runner.__name__} has "
                f"{', '.join(only_run) or 'none other'}"
                + (f"; not parameters: {', '.join(stray)}" if stray else "")
                + ("; their order differs" if want != have and not (only_it or only_run) else "")
            )
        return runner

    return check


def _parameter(q: inspect.Parameter) -> tuple[str, str, str, str]:
    """A parameter as :func:`runs` compares it: name, kind, default and annotation (as written)."""
    written = q.annotation if isinstance(q.annotation, str) else inspect.formatannotation(q.annotation)
    if q.annotation is inspect.Parameter.empty:
        written = ""
    return q.name, q.kind.name, repr(q.default), written


def _show(q: tuple[str, str, str, str]) -> str:
    name, kind, default, annotation = q
    shown = name + (f": {annotation}" if annotation else "")
    shown += "" if default == repr(inspect.Parameter.empty) else f" = {default}"
    return (
        {"VAR_POSITIONAL": "*", "VAR_KEYWORD": "**"}.get(kind, "")
        + shown
        + (" (positional)" if kind in ("POSITIONAL_ONLY", "POSITIONAL_OR_KEYWORD") else "")
    )
