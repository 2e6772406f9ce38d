"""The ``distnav`` command line.

    distnav demo [--out DIR]                      quick variant of every reproduction + a report page
    distnav reproduce NAME --out DIR [options]    one paper experiment (``distnav reproduce --help`` lists them)
    distnav uwb ... / distnav gnss ...            real-data commands (see their --help)

Bad input ends with ``error: <what is wrong>`` and exit code 2, never a bare traceback, and is found before any
work: option values when they are parsed (:mod:`distnav.options`), then :func:`check_arguments` (``--out`` is
created, ``--ranks`` needs ``--backend mpi``, which needs the ``mpi`` extra) before a command or experiment runs.
"""

from __future__ import annotations

import argparse
import importlib
import importlib.util
import logging
import os
import sys
import time
import warnings
from collections.abc import Callable, Sequence
from pathlib import Path

from distnav import __version__
from distnav.commands import add_backend_arguments
from distnav.errors import DistnavError, UsageError
from distnav.experiments import EXPERIMENTS, available, load
from distnav.experiments.common import ExperimentContext, Progress
from distnav.options import output_folder, probe_output_folder, seed
from distnav.output import set_file_writer

# real-data command groups; each module defines ``register(subparsers)``
COMMAND_MODULES = ("distnav.commands.uwb", "distnav.commands.gnss")


def _add_common(p: argparse.ArgumentParser) -> None:
    p.add_argument("--seed", type=seed, default=0, help="seed of every random draw, 0 or more (default 0)")
    add_backend_arguments(p)
    p.add_argument("--no-progress", action="store_true", help="do not print progress")


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="distnav", description="Distributed estimation over sensor networks.")
    parser.add_argument("--version", action="version", version=f"distnav {__version__}")
    sub = parser.add_subparsers(dest="command", required=True)

    demo = sub.add_parser("demo", help="run the quick variant of every reproduction and write a report")
    demo.add_argument("--out", type=output_folder, default=Path("distnav-demo"),
                      help="report folder (default distnav-demo)")
    demo.add_argument("--only", nargs="+", choices=list(EXPERIMENTS), help="run only these experiments")
    _add_common(demo)

    rep = sub.add_parser("reproduce", help="reproduce a paper experiment (figures + results.json)")
    rep_sub = rep.add_subparsers(dest="experiment", required=True)
    for name in available():
        mod = load(name)
        p = rep_sub.add_parser(name, help=getattr(mod, "TITLE", name))
        p.add_argument("--out", type=output_folder, required=True, help="output folder")
        p.add_argument("--quick", action="store_true", help="the small variant used by `distnav demo`")
        _add_common(p)
        if hasattr(mod, "add_arguments"):
            mod.add_arguments(p)

    for modname in COMMAND_MODULES:
        if importlib.util.find_spec(modname) is not None:
            importlib.import_module(modname).register(sub)
    return parser


def _context(args: argparse.Namespace, out_dir: Path, quick: bool) -> ExperimentContext:
    opts = {k: v for k, v in vars(args).items()
            if k not in {"command", "experiment", "out", "quick", "seed", "backend", "no_progress", "only", "func",
                         "ranks"}}
    return ExperimentContext(out_dir=out_dir, quick=quick, backend=args.backend, seed=args.seed,
                             progress=Progress(enabled=not args.no_progress), options=opts)


def _run_demo(args: argparse.Namespace) -> int:
    from distnav.experiments.report import write_report

    names = args.only or available()
    entries = []
    t_all = time.perf_counter()
    for name in names:
        mod = load(name)
        ctx = _context(args, args.out / name, quick=True)
        if ctx.is_root:
            print(f"[{names.index(name) + 1}/{len(names)}] {getattr(mod, 'TITLE', name)}", file=sys.stderr, flush=True)
        t0 = time.perf_counter()
        results = mod.run(ctx)
        entries.append((name, getattr(mod, "TITLE", name), ctx, results, time.perf_counter() - t0))
    if entries and entries[0][2].is_root:
        index = write_report(args.out, entries)
        print(f"report: {index} ({time.perf_counter() - t_all:.1f} s)", flush=True)
    return 0


def _run_reproduce(args: argparse.Namespace) -> int:
    mod = load(args.experiment)
    ctx = _context(args, args.out, quick=args.quick)
    mod.run(ctx)
    if ctx.is_root:
        print(f"results: {args.out / 'results.json'}", flush=True)
    return 0


def _check_mpi_launch(args: argparse.Namespace) -> None:
    from distnav.exchange.mpi import world_rank, world_size

    size = world_size()
    if args.ranks is not None and size != args.ranks:
        raise DistnavError(
            f"--ranks {args.ranks} was asked for but MPI reports {size} rank(s) on rank {world_rank()}: the launcher "
            f"does not match this MPI (use the mpiexec of the same installation, e.g. .venv/bin/mpiexec)"
        )
    if size == 1 and world_rank() == 0:
        print("warning: --backend mpi with a single rank; launch with mpiexec -n N python -m mpi4py -m distnav ...",
              file=sys.stderr)


def check_arguments(args: argparse.Namespace, *, probe_out: bool = True) -> None:
    """What the parser cannot check alone, before any work; raises :class:`UsageError`.

    ``--ranks`` without ``--backend mpi`` (it would be ignored), ``--backend mpi`` without the ``mpi`` extra, and
    ``--out``: with ``probe_out``, proved creatable and writable (:func:`~distnav.options.probe_output_folder`), so a
    folder that cannot be made stops the run now; under MPI only rank 0 probes."""
    backend = getattr(args, "backend", "inprocess")
    if getattr(args, "ranks", None) is not None and backend != "mpi":
        raise UsageError(f"--ranks {args.ranks} applies only with --backend mpi (launched with mpiexec -n N)")
    if backend == "mpi":
        from distnav._optional import require

        require("mpi4py.MPI", "mpi")
    out = getattr(args, "out", None)
    if out is not None and probe_out:
        probe_output_folder(out)


def _main_mpi(args: argparse.Namespace) -> int:
    """Run under MPI: any failure on any rank aborts the whole job with a message naming the rank."""
    from distnav._optional import require

    MPI = require("mpi4py.MPI", "mpi")
    rank = MPI.COMM_WORLD.Get_rank()
    if rank != 0:  # one writer, one voice: rank 0 writes files and prints; errors still reach stderr from any rank
        set_file_writer(False)
        sys.stdout = open(os.devnull, "w")  # noqa: SIM115 - lives for the whole process
    try:
        check_arguments(args, probe_out=rank == 0)
        _check_mpi_launch(args)
        return _dispatch(args)
    except BaseException as exc:  # noqa: BLE001 - every failure must end all ranks
        code = 2 if isinstance(exc, DistnavError) else 1
        print(f"error on MPI rank {rank} of {MPI.COMM_WORLD.Get_size()}: {type(exc).__name__}: {exc}",
              file=sys.stderr, flush=True)
        MPI.COMM_WORLD.Abort(code)
        return code  # pragma: no cover - Abort does not return


def _dispatch(args: argparse.Namespace) -> int:
    if args.command == "demo":
        return _run_demo(args)
    if args.command == "reproduce":
        return _run_reproduce(args)
    return int(args.func(args) or 0)


class _CliLogHandler(logging.StreamHandler):  # type: ignore[type-arg]
    """``warning: <message>`` on the current stderr (looked up per record, so redirection and pytest's capture
    see it)."""

    def __init__(self) -> None:
        super().__init__()
        self.setFormatter(logging.Formatter("%(message)s"))

    def emit(self, record: logging.LogRecord) -> None:
        self.stream = sys.stderr  # not setStream(): that flushes the previous stream, which may be closed
        record = logging.makeLogRecord(record.__dict__)
        record.msg, record.args = f"{record.levelname.lower()}: {record.getMessage()}", None
        super().emit(record)


def _configure_logging() -> Callable[[], None]:
    """Library modules log through :mod:`logging` (loggers ``distnav.*``) and never print; the CLI shows their
    warnings and errors on stderr as ``warning: ...`` while it runs. An application embedding distnav configures
    logging itself. Returns the function that undoes this (so an in-process ``main`` leaves logging as it was)."""
    logger = logging.getLogger("distnav")
    if any(isinstance(h, _CliLogHandler) for h in logger.handlers):
        return lambda: None
    handler, level = _CliLogHandler(), logger.level
    logger.addHandler(handler)
    if level == logging.NOTSET:
        logger.setLevel(logging.WARNING)

    def undo() -> None:
        logger.removeHandler(handler)
        logger.setLevel(level)

    return undo


def _show_warning(message: Warning | str, category: type[Warning], filename: str, lineno: int,
                  file: object = None, line: str | None = None) -> None:
    """Library warnings (e.g. :class:`~distnav.algorithms.consensus.ConsensusWarning`) as ``warning: ...`` lines,
    without the source location a user cannot act on."""
    print(f"warning: {message}", file=sys.stderr)


def _user_error(exc: BaseException) -> str:
    if isinstance(exc, FileNotFoundError) and exc.filename:
        return f"error: file not found: {exc.filename}"
    if isinstance(exc, OSError) and exc.filename:
        return f"error: {exc.strerror or exc}: {exc.filename}"
    return f"error: {exc}"


def main(argv: Sequence[str] | None = None) -> int:
    """The ``distnav`` command: 0 on success, 2 on a user error (``error: ...`` on stderr), 1 when a command
    computed nothing usable. ``argparse`` ends bad option values with ``SystemExit(2)``."""
    undo_logging = _configure_logging()
    try:
        with warnings.catch_warnings():
            warnings.showwarning = _show_warning
            return _main(argv)
    finally:
        undo_logging()


def _main(argv: Sequence[str] | None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if getattr(args, "backend", "inprocess") == "mpi":
        try:  # every rank fails alike here, before MPI starts
            check_arguments(args, probe_out=False)
        except DistnavError as exc:
            print(_user_error(exc), file=sys.stderr)
            return 2
        return _main_mpi(args)  # checks again inside, where a failure on one rank aborts them all
    try:
        check_arguments(args)
        return _dispatch(args)
    except DistnavError as exc:
        print(_user_error(exc), file=sys.stderr)
        return 2
    except OSError as exc:  # a file that vanished or could not be written mid-run: say which, no traceback
        print(_user_error(exc), file=sys.stderr)
        return 2


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
