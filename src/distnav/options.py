"""Checked types for command-line options, shared by the CLI, the experiments' and the commands' parsers.

Each is an ``argparse`` ``type=`` callable: a bad value ends the run at parse time, before any work, with
``distnav ...: error: argument --NAME: <what is wrong>`` and exit code 2. Beside :mod:`distnav.output` in the
layers (it imports only :mod:`distnav.errors` and the standard library), for experiments, commands and the CLI.

:func:`output_folder` checks ``--out`` when it is parsed (not an existing file, under a folder); the CLI then
proves with :func:`probe_output_folder` that the folder can be created and written before running anything, so a
folder that cannot be created is reported as such.
"""

from __future__ import annotations

import argparse
import math
import os
from datetime import datetime
from pathlib import Path

from distnav.errors import UsageError

__all__ = [
    "check_output_folder",
    "existing_file",
    "finite_float",
    "iso_datetime",
    "nonnegative_float",
    "nonnegative_int",
    "output_folder",
    "positive_float",
    "positive_int",
    "probe_output_folder",
    "seed",
]


def _int(text: str) -> int:
    try:
        return int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a whole number, got {text!r}") from None


def _float(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number, got {text!r}") from None
    if not math.isfinite(value):
        raise argparse.ArgumentTypeError(f"expected a finite number, got {text!r}")
    return value


def _whole(text: str, minimum: int, message: str) -> int:
    """``text`` as a whole number ≥ ``minimum``, else ``message`` (``{}`` stands for the value)."""
    value = _int(text)
    if value < minimum:
        raise argparse.ArgumentTypeError(message.format(value))
    return value


def _number(text: str, *, zero_ok: bool, message: str) -> float:
    """``text`` as a finite number > 0 (``≥ 0`` with ``zero_ok``), else ``message`` (``{}`` stands for the text)."""
    value = _float(text)
    if value < 0.0 or (value == 0.0 and not zero_ok):
        raise argparse.ArgumentTypeError(message.format(text))
    return value


def positive_int(text: str) -> int:
    """A whole number ≥ 1 (iterations, epochs, instances, ranks)."""
    return _whole(text, 1, "must be at least 1, got {}")


def nonnegative_int(text: str) -> int:
    """A whole number ≥ 0 (consensus rounds, where 0 means none)."""
    return _whole(text, 0, "must be 0 or more, got {}")


def seed(text: str) -> int:
    """A seed of :func:`numpy.random.default_rng`: a whole number ≥ 0."""
    return _whole(text, 0, "a seed must be 0 or more, got {}")


def finite_float(text: str) -> float:
    """Any finite number (no ``nan``, no ``inf``)."""
    return _float(text)


def positive_float(text: str) -> float:
    """A finite number > 0 (a standard deviation, a scale, a step)."""
    return _number(text, zero_ok=False, message="must be greater than 0, got {}")


def nonnegative_float(text: str) -> float:
    """A finite number ≥ 0."""
    return _number(text, zero_ok=True, message="must be 0 or more, got {}")


def iso_datetime(text: str) -> str:
    """An ISO 8601 date and time such as ``2024-01-10T06:00`` (returned as given, checked here)."""
    try:
        datetime.fromisoformat(text)
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"expected an ISO date and time such as 2024-01-10T06:00, got {text!r}"
        ) from None
    return text


def existing_file(text: str) -> Path:
    """A file that exists and is readable."""
    path = Path(text)
    if not path.exists():
        raise argparse.ArgumentTypeError(f"no such file: {text}")
    if not path.is_file():
        raise argparse.ArgumentTypeError(f"not a file: {text}")
    if not os.access(path, os.R_OK):
        raise argparse.ArgumentTypeError(f"cannot read {text}: permission denied")
    return path


def _nearest_existing(path: Path) -> Path:
    p = path.absolute()
    while not p.exists() and p != p.parent:
        p = p.parent
    return p


def check_output_folder(path: str | Path) -> Path:
    """An output folder: an existing folder or one that can be made (not an existing file, nor under one);
    :class:`UsageError` otherwise. Checks only, creates nothing (see :func:`probe_output_folder`)."""
    text = str(path)
    if not text:
        raise UsageError("an empty path is not an output folder")
    p = Path(text)
    if p.exists() and not p.is_dir():
        raise UsageError(f"output folder {text} is an existing file (give a folder to write into)")
    base = _nearest_existing(p)
    if not base.is_dir():
        raise UsageError(f"cannot create output folder {text}: {base} is a file, not a folder")
    return p


def output_folder(text: str) -> Path:
    """``argparse`` type of ``--out``: :func:`check_output_folder` at parse time."""
    try:
        return check_output_folder(text)
    except UsageError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


def probe_output_folder(path: str | Path) -> Path:
    """Prove, before any work, that the output folder can be created and written: create what is missing, check
    write permission, then remove again the folders this call created (a failed run leaves no empty folder
    behind; the writers create it when they write). :class:`UsageError` names the folder and the reason."""
    p = check_output_folder(path)
    missing = []
    q = p.absolute()
    while not q.exists():
        missing.append(q)
        q = q.parent
    try:
        for d in reversed(missing):
            d.mkdir()
        if not os.access(p, os.W_OK | os.X_OK):
            raise UsageError(f"cannot write into output folder {p}: permission denied")
    except FileExistsError:
        raise UsageError(f"cannot create output folder {p}: a file of that name appeared") from None
    except OSError as exc:
        raise UsageError(f"cannot create output folder {p}: {exc.strerror or exc}") from None
    finally:
        for d in missing:
            if d.is_dir():
                d.rmdir()
    return p
