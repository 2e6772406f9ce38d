"""Checked types for command-line options, shared by the CLI, the experiments' and the commands' parsers.

Each is an ``argparse`` ``type=`` callable: a bad value ends the run at parse time, before any work, with
``distnav ...: error: argument --NAME: <what is wrong>`` and exit code 2. Beside :mod:`distnav.output` in the
layers (it imports only :mod:`distnav.errors` and the standard library), for experiments, commands and the CLI.

:func:`output_folder` checks ``--out`` when it is parsed (not an existing file, under a folder); the CLI then
proves with :func:`probe_output_folder` that the folder can be created and written before running anything, so a
folder that cannot be created is reported as such.

No command writes over its inputs or over a file it did not create (:func:`check_output_spares`, before any work):
no input file may lie inside ``--out`` (real paths: symbolic links and ``..`` resolved), ``--out`` may not be an
input folder, and an existing ``--out`` may hold only files that distnav wrote there — the ones listed in its
:data:`OUTPUT_MANIFEST`, which :func:`record_outputs` updates after every run.
"""

from __future__ import annotations

import argparse
import dataclasses
import itertools
import math
import os
from collections.abc import Iterable, Iterator
from datetime import datetime
from pathlib import Path
from typing import Any

from distnav.errors import UsageError

__all__ = [
    "OUTPUT_MANIFEST",
    "check_output_folder",
    "check_output_spares",
    "check_repeated_inputs",
    "check_repeated_options",
    "check_node_outputs",
    "node_output_files",
    "input_paths",
    "record_outputs",
    "existing_file",
    "fields_from_args",
    "finite_float",
    "IntUpTo",
    "add_size_option",
    "int_up_to",
    "jobs_count",
    "iso_datetime",
    "nonnegative_float",
    "nonnegative_int",
    "output_folder",
    "positive_float",
    "positive_int",
    "probe_output_folder",
    "seed",
]


def fields_from_args(args: argparse.Namespace, options_type: type[Any], *, but: Iterable[str] = ()) -> dict[str, Any]:
    """The fields of the options dataclass ``options_type`` that the command line gives under the same name (an
    option ``--loss-scale-m`` for a field ``loss_scale_m``), as keyword arguments; ``but`` names the fields the
    command sets itself (a default that depends on another option, a value converted)."""
    skip = set(but)
    return {
        f.name: getattr(args, f.name)
        for f in dataclasses.fields(options_type)
        if f.name not in skip and hasattr(args, f.name)
    }


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


@dataclasses.dataclass(frozen=True)
class IntUpTo:
    """The ``type=`` of a size option (instances, iterations, epochs, rounds, workers): a whole number in
    ``minimum … maximum``, refused at parse time above ``maximum`` with ``why`` (what one unit costs, so what the
    limit buys on one machine): ``argument --NAME: at most 1,000, got 1000000000 (WHY)``, exit code 2."""

    maximum: int
    why: str
    minimum: int = 1

    @property
    def __name__(self) -> str:  # argparse names a type by it
        return f"int_up_to_{self.maximum}"

    def __call__(self, text: str) -> int:
        low = "must be 0 or more, got {}" if self.minimum == 0 else f"must be at least {self.minimum}, got {{}}"
        value = _whole(text, self.minimum, low)
        if value > self.maximum:
            raise argparse.ArgumentTypeError(f"at most {self.maximum:,}, got {text.strip()} ({self.why})")
        return value


def int_up_to(maximum: int, why: str, *, minimum: int = 1) -> IntUpTo:
    """:class:`IntUpTo`: ``type=int_up_to(MAX_EPOCHS, EPOCHS_WHY)``."""
    return IntUpTo(maximum, why, minimum)


def add_size_option(
    parser: argparse.ArgumentParser, flag: str, size: IntUpTo, *, default: int | None, help: str
) -> None:
    """Add the size option ``flag`` of type ``size`` to ``parser``; its help ends with the limit and its reason."""
    parser.add_argument(flag, type=size, default=default, help=f"{help}; at most {size.maximum:,}: {size.why}")


#: The most worker processes ``--jobs`` starts (experiments, ``demo``, ``reproduce-all``): each is a Python process
#: with numpy, scipy and the experiment loaded, 70 MB resident before its first run (measured), so 64 hold ≥ 4.5 GB;
#: more buys nothing on one machine.
jobs_count = int_up_to(64, "each worker is a Python process of ≥ 70 MB before its first run: 64 hold ≥ 4.5 GB")


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
        moment = datetime.fromisoformat(text)
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"expected an ISO date and time such as 2024-01-10T06:00, got {text!r}"
        ) from None
    if moment.tzinfo is not None:  # numpy dropped the zone with a deprecation warning: a shifted, silent window
        raise argparse.ArgumentTypeError(
            f"{text!r}: times are GPS time, without a time zone (write e.g. {moment.replace(tzinfo=None).isoformat()})"
        )
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


OUTPUT_MANIFEST = ".distnav-written"
"""The file in an output folder that lists (one relative path a line) the files distnav wrote there."""


def input_paths(values: Iterable[object]) -> list[Path]:
    """The real paths of the existing files and folders named in ``values`` (option values: strings, paths, lists of
    them); anything else (numbers, names, comma lists) is not a path and is skipped."""
    found: list[Path] = []
    for value in values:
        if isinstance(value, (list, tuple)):
            found += input_paths(value)
        elif isinstance(value, (str, Path)) and str(value) and os.path.exists(value):
            found.append(Path(os.path.realpath(value)))
    return found


def check_repeated_inputs(args: argparse.Namespace) -> None:
    """Refuse a file named twice in one option's list (``--bias A A``, ``--sp3 A ./A``) and an experiment named
    twice in ``--only``: never meant, and it would count the file's data twice, compare a product with itself or
    run an experiment twice. Station files (``--obs``, ``--rinex``) are left to their readers, which name the
    station given twice (also in two different files)."""
    for key, value in vars(args).items():
        if not isinstance(value, (list, tuple)) or key in ("obs", "rinex"):
            continue
        twice = sorted({str(v) for v in value if key == "only" and list(value).count(v) > 1})
        if twice:  # --only NAME NAME: the same experiment run twice, into one folder
            raise UsageError(f"--only names {', '.join(twice)} twice")
        seen: dict[Path, object] = {}
        for item in value:
            if not isinstance(item, (str, Path)) or not str(item) or not os.path.isfile(item):
                continue
            real = Path(os.path.realpath(item))
            if real in seen:
                same = f" (as {seen[real]})" if str(seen[real]) != str(item) else ""
                raise UsageError(f"--{key.replace('_', '-')}: {item} is given twice{same}")
            seen[real] = item


def check_repeated_options(parser: argparse.ArgumentParser, words: list[str]) -> None:
    """Refuse an option given twice on one command line (``--obs A --obs B``, ``--ranges X --ranges Y``): argparse
    keeps the last silently, so the first files were dropped without a word. Flags (no value) and ``append``
    options may repeat."""
    leaf = parser
    for w in words:  # the (sub)command the words name: its parser holds the options
        subs = [a for a in leaf._actions if isinstance(a, argparse._SubParsersAction)]
        if subs and w in subs[0].choices:
            leaf = subs[0].choices[w]
    table = leaf._option_string_actions
    seen: dict[str, str] = {}
    for w in words:
        if not w.startswith("--") or w == "--":
            continue
        flag = w.split("=", 1)[0]
        matches = [table[flag]] if flag in table else [a for f, a in table.items() if f.startswith(flag)]
        if (
            len({id(a) for a in matches}) != 1
            or matches[0].nargs == 0
            or isinstance(matches[0], argparse._AppendAction)
        ):
            continue  # a flag given twice drops nothing; append options collect
        dest = matches[0].dest
        if dest in seen:
            also = f" (also as {seen[dest]})" if seen[dest] != flag else ""
            raise UsageError(f"{flag} is given twice{also}: give it once, with all its values")
        seen[dest] = flag


def _files_under(folder: Path) -> Iterator[str]:
    """Every file under ``folder`` as a relative POSIX path (the manifest itself left out), lazily."""
    for root, _, names in os.walk(folder):
        for name in names:
            if not (Path(root) == folder and name == OUTPUT_MANIFEST):
                yield Path(root, name).relative_to(folder).as_posix()


def _written_by_distnav(folder: Path) -> set[str]:
    try:
        return set((folder / OUTPUT_MANIFEST).read_text(encoding="utf-8").splitlines())
    except (FileNotFoundError, UnicodeDecodeError):
        return set()


def check_output_spares(out: str | Path, inputs: Iterable[Path]) -> None:
    """Refuse (:class:`UsageError`, before any work) an output folder whose writing could replace a file the user
    did not get from distnav: an input file inside it (real paths), an input folder that is it or lies inside it,
    or, in an existing folder, a file distnav did not write there (not in its :data:`OUTPUT_MANIFEST`; the walk
    stops at the fourth such file, so ``--out ~`` is refused quickly)."""
    real_out = Path(os.path.realpath(out))
    for path in inputs:
        if path == real_out or real_out in path.parents:
            kind = "folder" if path.is_dir() else "file"
            raise UsageError(
                f"input {kind} {path} lies inside the output folder {out} ({real_out}), where its outputs could "
                f"replace it: give another --out"
            )
    if not real_out.is_dir():
        return
    known = _written_by_distnav(real_out)
    foreign = list(itertools.islice((f for f in _files_under(real_out) if f not in known), 4))
    if foreign:
        shown = ", ".join(foreign[:3]) + (" and more" if len(foreign) > 3 else "")
        raise UsageError(
            f"output folder {out} holds files distnav did not write there ({shown}); its outputs could replace "
            f"them: give a new or empty --out (or move those files away)"
        )


def node_output_files(args: argparse.Namespace) -> list[str]:
    """The files one node of a field network writes in its shared ``--out`` (``node-ID.json``, ``.log``,
    ``.stderr``): what :func:`check_node_outputs` guards."""
    return [f"node-{args.id}.{ext}" for ext in ("json", "log", "stderr")]


def check_node_outputs(out: str | Path, own_files: Iterable[str], inputs: Iterable[Path]) -> None:
    """The rule of :func:`check_output_spares` for one node of a field network, whose ``--out`` is a folder it
    shares with the other nodes of its machine (and often with their description): it writes only ``own_files``
    (``node-ID.json``, ``node-ID.log``, ...), so it refuses (:class:`UsageError`) only an input that is one of
    them; the other nodes' files and the description beside them are not its to replace."""
    real_out = Path(os.path.realpath(out))
    mine = {real_out / name for name in own_files}
    for path in inputs:
        if path in mine:
            raise UsageError(
                f"input file {path} is the file this node writes in {out} ({path.name}): give another --out"
            )


def record_outputs(out: str | Path) -> None:
    """List every file now under ``out`` in its :data:`OUTPUT_MANIFEST` (after a run; all of them are distnav's,
    as :func:`check_output_spares` refused a folder holding any other). Written atomically; a folder that does not
    exist is left alone."""
    folder = Path(out)
    if not folder.is_dir():
        return
    tmp = folder / f".{OUTPUT_MANIFEST}.{os.getpid()}.tmp"
    tmp.write_text("".join(f"{name}\n" for name in sorted(_files_under(folder)) if name != tmp.name), encoding="utf-8")
    os.replace(tmp, folder / OUTPUT_MANIFEST)
