"""Front-door checks of argument types shared by every layer (issue 29 item 2): a whole number where one is
meant, real numbers where an array of them is meant, and a network size the machine can hold. Each raises the
caller's own error type (``error=``) with a message naming the argument and what to change; numpy's own messages
(``'float' object cannot be interpreted as an integer``, a ``ComplexWarning`` and a silently dropped imaginary part,
``Unable to allocate 8.00 TiB``) never reach the user.
"""

from __future__ import annotations

import dataclasses
import math
import numbers
import operator
import os
from typing import Any

import numpy as np

from distnav.errors import DistnavError

__all__ = ["affordable_nodes", "check_field_types", "real_array", "real_number", "whole_number"]

#: Bytes every node of a network costs at the least (its links both ways in the graph's CSR arrays, its id, its
#: value); a network above physical memory ÷ this cannot be built, so it is refused before numpy tries.
MIN_BYTES_PER_NODE = 64


def whole_number(
    value: object, name: str, *, minimum: int | None = 0, error: type[DistnavError], allow_float: bool = True
) -> int:
    """``value`` as an ``int`` ≥ ``minimum`` (None: any): an ``int``, a numpy integer or (``allow_float``, for a
    check whose caller keeps using the value it was given: not) a float with no fraction (``3.0``); not
    ``True``/``False``, not ``2.7``, not NaN, not a string."""
    if isinstance(value, (bool, np.bool_)):
        raise error(f"{name} must be a whole number, got {value!r} (a bool)")
    if isinstance(value, numbers.Integral):
        number = operator.index(value)
    elif allow_float and isinstance(value, numbers.Real) and math.isfinite(float(value)) and float(value).is_integer():
        number = int(float(value))
    else:
        raise error(f"{name} must be a whole number, got {value!r} ({type(value).__name__})")
    if minimum is not None and number < minimum:
        raise error(f"{name} must be ≥ {minimum}, got {number}")
    return number


def real_number(
    value: object,
    name: str,
    *,
    error: type[DistnavError],
    minimum: float | None = None,
    positive: bool = False,
    below: float | None = None,
    unit: str = "",
) -> float:
    """``value`` as a finite ``float``: an ``int``, a float or a numpy real; not a bool, a complex number, a string
    or None. ``minimum`` (inclusive), ``positive`` (> 0) and ``below`` (exclusive) bound it; ``unit`` is named in
    the message (``"m"``, ``"rad"``)."""
    what = f"{name} must be a {'positive ' if positive else ''}number{f' of {unit}' if unit else ''}"
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, numbers.Real):
        raise error(f"{what}, got {value!r} ({type(value).__name__})")
    number = float(value)
    if not np.isfinite(number):
        raise error(f"{what}, got {number!r}")
    if positive and not number > 0.0:
        raise error(f"{what}, got {number!r}")
    if minimum is not None and number < minimum:
        raise error(f"{name} must be {minimum:g} or more{f' ({unit})' if unit else ''}, got {number!r}")
    if below is not None and not number < below:
        raise error(f"{name} must be below {below:g}{f' ({unit})' if unit else ''}, got {number!r}")
    return number


def real_array(values: object, name: str, *, error: type[DistnavError]) -> np.ndarray:
    """``values`` as a float64 array; complex numbers (their imaginary part would be dropped), booleans, strings
    and objects are refused by name."""
    arr = np.asarray(values)
    kind = arr.dtype.kind
    if kind == "c":
        raise error(
            f"{name} are complex numbers ({arr.dtype}); distnav estimates real quantities: pass the real "
            f"and imaginary parts as separate entries"
        )
    if kind == "b":
        raise error(f"{name} are booleans; pass numbers (e.g. values.astype(float) if 0/1 is meant)")
    if kind not in "iuf":
        raise error(
            f"{name} must be numbers, got an array of {arr.dtype} (e.g. {arr.flat[0]!r})"
            if arr.size
            else f"{name} must be numbers, got an empty array of {arr.dtype}"
        )
    return arr.astype(float, copy=False)


def _physical_memory_bytes() -> int | None:
    try:
        return int(os.sysconf("SC_PAGE_SIZE")) * int(os.sysconf("SC_PHYS_PAGES"))
    except (ValueError, OSError, AttributeError):  # not on every platform
        return None


NETWORK_HINT = "(for networks beyond one machine: MPI across hosts, docs/scale.md)"


def affordable_nodes(
    n_nodes: int, what: str, *, error: type[DistnavError], items: str = "nodes", hint: str = NETWORK_HINT
) -> None:
    """Refuse a network of ``n_nodes`` (or of that many links: ``items="links"``; or any other ``items`` with its
    own ``hint``) that cannot fit in this machine's memory (at :data:`MIN_BYTES_PER_NODE` each), naming the size
    and the memory."""
    memory = _physical_memory_bytes()
    need = n_nodes * MIN_BYTES_PER_NODE
    if memory is not None and need > memory:
        raise error(
            f"{what} of {n_nodes:,} {items} needs at least {need >> 30:,} GiB of memory; this machine has "
            f"{memory / 2**30:,.1f} GiB{f' {hint}' if hint else ''}"
        )


#: the annotations :func:`check_field_types` checks (as written in a module with ``from __future__ import annotations``)
_WHOLE = {"int", "int | None"}
_REAL = {"float", "float | None"}
_FLAG = {"bool"}
_TEXT = {"str", "str | None"}
_MANY = ("Sequence[", "tuple[")  # a list, tuple or array of values (their entries are the class's to check)


def check_field_types(options: Any, *, error: type[DistnavError]) -> None:
    """Check the type of every field of a frozen options dataclass annotated ``int``, ``float``, ``bool``, ``str``,
    ``Sequence[...]`` or ``tuple[...]`` (each also ``| None``), as the first line of its ``__post_init__``: a whole
    number where ``int`` is written (``3.0`` is stored as ``3``), a finite real number where ``float`` is (no NaN,
    no ``inf``: a limit that is not wanted is ``None`` or a large number), ``True``/``False`` where ``bool`` is, a
    string where ``str`` is, a list, tuple or array where a sequence is; ``None`` only where the
    annotation allows it. The error names the field (``OptionsClass.field must be ...``); the class's own checks
    of ranges and choices follow. Issue 29 item 2: before, ``2.7`` rounds, ``None`` and complex numbers reached a
    comparison and ended in Python's ``TypeError``, or were stored and failed (or were silently used) later."""
    where = type(options).__name__
    for field in dataclasses.fields(options):
        kind = field.type if isinstance(field.type, str) else getattr(field.type, "__name__", "")
        value = getattr(options, field.name)
        if value is None and kind.endswith("| None"):
            continue
        name = f"{where}.{field.name}"
        if kind in _WHOLE:
            object.__setattr__(options, field.name, whole_number(value, name, minimum=None, error=error))
        elif kind in _REAL:
            object.__setattr__(options, field.name, real_number(value, name, error=error))
        elif kind in _FLAG and not isinstance(value, (bool, np.bool_)):
            raise error(f"{name} must be True or False, got {value!r} ({type(value).__name__})")
        elif kind in _TEXT and not isinstance(value, str):
            raise error(f"{name} must be a string, got {value!r} ({type(value).__name__})")
        elif kind.startswith(_MANY):
            _check_entries(value, name, kind, error)


def _check_entries(value: object, name: str, kind: str, error: type[DistnavError]) -> None:
    """A list, tuple or array whose entries are strings (``Sequence[str]``, ``tuple[str, ...]``) or finite real
    numbers (``Sequence[float]``, ``tuple[float, float]``) as the annotation says."""
    if not isinstance(value, (list, tuple, np.ndarray)):
        raise error(f"{name} must be a list or tuple, got {value!r} ({type(value).__name__})")
    entries = {part.strip() for part in kind[kind.index("[") + 1 : kind.rindex("]")].split(",")} - {"..."}
    for i, entry in enumerate(value):
        if entries == {"str"} and not isinstance(entry, str):
            raise error(f"{name}[{i}] must be a string, got {entry!r} ({type(entry).__name__})")
        if entries == {"float"}:
            real_number(entry, f"{name}[{i}]", error=error)
