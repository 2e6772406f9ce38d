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
import signal
import sys
import time
import warnings
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any, TextIO

from distnav import __version__
from distnav.errors import DistnavError, UsageError
from distnav.experiments import EXPERIMENTS, available, load
from distnav.options import (
    add_size_option,
    check_node_outputs,
    check_output_spares,
    check_repeated_inputs,
    check_repeated_options,
    input_paths,
    jobs_count,
    output_folder,
    probe_output_folder,
    record_outputs,
    seed,
)

if TYPE_CHECKING:
    from distnav.experiments.common import ExperimentContext

# real-data command groups; each module defines ``register(subparsers)``
COMMAND_MODULES = (
    "distnav.commands.uwb",
    "distnav.commands.gnss",
    "distnav.commands.reproduce_all",
    "distnav.commands.field",
)

#: Every top-level command and its one-line help: ``distnav --help`` and ``--version`` are answered from this table
#: without importing the commands, the experiments, numpy or scipy (issue 29: ≤ 0.3 s; the full parser costs
#: 1.5 CPU-s). tests/test_cli_startup.py holds it equal to the full parser's; a module added to
#: :data:`COMMAND_MODULES` without its line here makes ``--help`` take the full (slow) path, never a wrong one.
TOP_LEVEL_HELP: dict[str, str] = {
    "demo": "run the quick variant of every reproduction and write a report",
    "reproduce": "reproduce a paper experiment (figures + results.json)",
    "uwb": "UWB anchor self-localization from inter-anchor range logs",
    "gnss": "real-data GNSS commands (code biases, ionosphere)",
    "reproduce-all": "every paper reproduction at full size, with their run times",
    "node": "run one node of a field network (its own program)",
    "field": "field networks: launch every node on this machine, make keys",
}
#: the top-level commands each module of :data:`COMMAND_MODULES` registers
COMMAND_NAMES: dict[str, tuple[str, ...]] = {
    "distnav.commands.uwb": ("uwb",),
    "distnav.commands.gnss": ("gnss",),
    "distnav.commands.reproduce_all": ("reproduce-all",),
    "distnav.commands.field": ("node", "field"),
}


def _add_common(p: argparse.ArgumentParser) -> None:
    from distnav.commands import add_backend_arguments

    p.add_argument("--seed", type=seed, default=0, help="seed of every random draw, 0 or more (default 0)")
    add_backend_arguments(p)
    p.add_argument("--no-progress", action="store_true", help="do not print progress")


def _top_parser() -> tuple[argparse.ArgumentParser, Any]:
    parser = argparse.ArgumentParser(prog="distnav", description="Distributed estimation over sensor networks.")
    parser.add_argument("--version", action="version", version=f"distnav {__version__}")
    return parser, parser.add_subparsers(dest="command", required=True)


def build_top_level_parser() -> argparse.ArgumentParser | None:
    """The top-level parser with every command named but none built (for ``--help`` / ``--version``, which need
    no more); None when a module of :data:`COMMAND_MODULES` has no line in :data:`TOP_LEVEL_HELP`."""
    if any(m not in COMMAND_NAMES for m in COMMAND_MODULES):
        return None
    parser, sub = _top_parser()
    names = ["demo", "reproduce"] + [n for m in COMMAND_MODULES for n in COMMAND_NAMES[m]]
    if any(n not in TOP_LEVEL_HELP for n in names):
        return None
    for name in names:
        sub.add_parser(name, help=TOP_LEVEL_HELP[name])
    return parser


def command_words(words: Sequence[str]) -> tuple[str | None, str | None]:
    """The command and, for ``reproduce``, the experiment named in ``words`` (None where not named): the top-level
    parser and ``reproduce`` take no option with a value, so the first word that is not an option is the command,
    and the next one after ``reproduce`` the experiment."""
    positional = [w for w in words if not w.startswith("-")]
    command = positional[0] if positional else None
    experiment = None
    if command == "reproduce" and len(words) > words.index("reproduce") + 1:
        following = words[words.index("reproduce") + 1]
        experiment = None if following.startswith("-") else following
    return command, experiment


def build_parser(words: Sequence[str] | None = None) -> argparse.ArgumentParser:
    """The CLI's parser. With ``words`` (the command line) only the command they name is built in full, every
    other one is named with its one-line help but not built, so a run imports only the modules of its own command
    (issue 32 item 7: building all cost 1.5 CPU-s, on every MPI rank); ``distnav reproduce NAME`` imports only that
    experiment. Without ``words``, or when they name no known command, everything is built (the same parser: the
    audit and tests/test_cli_startup.py compare the two)."""
    command, experiment = command_words(words) if words is not None else (None, None)
    if command not in TOP_LEVEL_HELP or build_top_level_parser() is None:
        command = None
    if command != "reproduce" or experiment not in EXPERIMENTS:
        experiment = None
    parser, sub = _top_parser()
    if command in (None, "demo"):
        _add_demo_parser(sub)
    else:
        sub.add_parser("demo", help=TOP_LEVEL_HELP["demo"])
    if command in (None, "reproduce"):
        _add_reproduce_parser(sub, only=experiment)
    else:
        sub.add_parser("reproduce", help=TOP_LEVEL_HELP["reproduce"])
    for modname in COMMAND_MODULES:
        if command is not None and command not in COMMAND_NAMES[modname]:
            for name in COMMAND_NAMES[modname]:
                sub.add_parser(name, help=TOP_LEVEL_HELP[name])
        elif importlib.util.find_spec(modname) is not None:
            importlib.import_module(modname).register(sub)
    return parser


def _add_demo_parser(sub: Any) -> None:
    demo = sub.add_parser("demo", help=TOP_LEVEL_HELP["demo"])
    demo.add_argument(
        "--out", type=output_folder, default=Path("distnav-demo"), help="report folder (default distnav-demo)"
    )
    demo.add_argument("--only", nargs="+", choices=list(EXPERIMENTS), help="run only these experiments")
    add_size_option(
        demo,
        "--jobs",
        jobs_count,
        default=1,
        help="run the experiments in this many processes, in-process backend only (default 1; `make demo` uses 2)",
    )
    _add_common(demo)


def _add_reproduce_parser(sub: Any, *, only: str | None) -> None:
    """``distnav reproduce NAME``: every experiment's options, or with ``only`` that experiment's alone (the others
    named, not imported)."""
    rep = sub.add_parser("reproduce", help=TOP_LEVEL_HELP["reproduce"])
    rep_sub = rep.add_subparsers(dest="experiment", required=True)
    for name in available():
        if only is not None and name != only:
            rep_sub.add_parser(name)
            continue
        mod = load(name)
        p = rep_sub.add_parser(name, help=getattr(mod, "TITLE", name))
        p.add_argument("--out", type=output_folder, required=True, help="output folder")
        p.add_argument("--quick", action="store_true", help="the small variant used by `distnav demo`")
        _add_common(p)
        if hasattr(mod, "add_arguments"):
            mod.add_arguments(p)


def _context(args: argparse.Namespace, out_dir: Path, quick: bool) -> ExperimentContext:
    from distnav.experiments.common import ExperimentContext, Progress

    opts = {
        k: v
        for k, v in vars(args).items()
        if k
        not in {
            "command",
            "experiment",
            "out",
            "quick",
            "seed",
            "backend",
            "no_progress",
            "only",
            "func",
            "ranks",
            "jobs",
        }
    }
    return ExperimentContext(
        out_dir=out_dir,
        quick=quick,
        backend=args.backend,
        seed=args.seed,
        progress=Progress(enabled=not args.no_progress),
        options=opts,
    )


#: Seconds each quick variant took in ``distnav demo --jobs 2`` (the project's shared 2-core machine, loaded): the
#: demo starts the longest first, so two processes finish close together. Only the order matters.
DEMO_SECONDS: dict[str, float] = {
    "qc": 48,
    "uwb-field": 38,
    "uwb": 21,
    "admm": 19,
    "ckf-ionosphere": 12,
    "codebias": 10,
    "consensus": 6,
    "ckf": 5,
}


class _LineStream:
    """stderr for a demo worker: the same stream, but not a terminal, so progress comes as whole lines (two
    processes drawing progress bars on one terminal garble each other)."""

    def __init__(self, stream: TextIO) -> None:
        self._stream = stream

    def write(self, text: str) -> int:
        return self._stream.write(text)

    def flush(self) -> None:
        self._stream.flush()

    def isatty(self) -> bool:
        return False

    def __getattr__(self, name: str) -> Any:
        return getattr(self._stream, name)


def _demo_worker_init() -> None:
    """In each demo worker: line progress, the CLI's warning lines, Ctrl-C left to the parent (which ends the
    pool)."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    sys.stderr = _LineStream(sys.stderr)
    _configure_logging()
    warnings.showwarning = _show_warning


def _demo_one(job: tuple[int, int, str, argparse.Namespace]) -> tuple[str, dict[str, Any], list[str], float, float]:
    """Run one quick variant: ``(name, results, figures written, wall seconds, CPU seconds)``."""
    index, total, name, args = job
    mod = load(name)
    ctx = _context(args, args.out / name, quick=True)
    if ctx.is_root:
        print(f"[{index}/{total}] {getattr(mod, 'TITLE', name)}", file=sys.stderr, flush=True)
    t0, c0 = time.perf_counter(), time.process_time()
    results = mod.run(ctx)
    return name, results, list(ctx.figures), time.perf_counter() - t0, time.process_time() - c0


def _run_demo(args: argparse.Namespace) -> int:
    """Every quick variant, then the report. With ``--jobs N`` > 1 (in-process backend only) the experiments run
    in N worker processes, the longest first (:data:`DEMO_SECONDS`); each is the same computation as alone (its
    own seeded generators, its own output folder), so the results are the same; only the progress lines of two
    experiments interleave (each names its experiment)."""
    from distnav.experiments.report import write_report

    names = args.only or available()
    jobs = [(i + 1, len(names), name, args) for i, name in enumerate(names)]
    n_workers = min(getattr(args, "jobs", None) or 1, len(names))
    t_all = time.perf_counter()
    done: dict[str, tuple[str, dict[str, Any], list[str], float, float]] = {}
    if n_workers <= 1:
        for job in jobs:
            done[job[2]] = _demo_one(job)
    else:
        if not args.no_progress:
            print(
                f"loading {len(names)} experiments (numpy, scipy, matplotlib), then running them in {n_workers} "
                f"processes",
                file=sys.stderr,
                flush=True,
            )
        for name in names:
            load(name)  # import every experiment (numpy, scipy, matplotlib) once, before the workers fork
        import multiprocessing

        method = "fork" if "fork" in multiprocessing.get_all_start_methods() and sys.platform == "linux" else None
        order = sorted(jobs, key=lambda job: -DEMO_SECONDS.get(job[2], 0.0))
        with multiprocessing.get_context(method).Pool(n_workers, initializer=_demo_worker_init) as pool:
            for result in pool.imap_unordered(_demo_one, order, chunksize=1):
                done[result[0]] = result
                if not args.no_progress:
                    print(
                        f"  ✓ {result[0]} done, {len(done)} of {len(names)} ({result[3]:.1f} s)",
                        file=sys.stderr,
                        flush=True,
                    )
    entries = []
    for name in names:
        _, results, figures, seconds, _ = done[name]
        ctx = _context(args, args.out / name, quick=True)
        ctx.figures.extend(figures)
        entries.append((name, getattr(load(name), "TITLE", name), ctx, results, seconds))
    if entries and entries[0][2].is_root:
        index = write_report(args.out, entries)
        cpu = sum(d[4] for d in done.values())
        print(
            f"report: {index} ({time.perf_counter() - t_all:.1f} s; experiments {cpu:.1f} CPU s in "
            f"{max(n_workers, 1)} process(es))",
            flush=True,
        )
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
        print(
            "warning: --backend mpi with a single rank; launch with mpiexec -n N python -m mpi4py -m distnav ...",
            file=sys.stderr,
        )


def check_arguments(args: argparse.Namespace, *, probe_out: bool = True) -> None:
    """What the parser cannot check alone, before any work; raises :class:`UsageError`.

    ``--ranks`` without ``--backend mpi`` (it would be ignored), ``--backend mpi`` without the ``mpi`` extra, and
    ``--out``: with ``probe_out``, proved creatable and writable (:func:`~distnav.options.probe_output_folder`), so a
    folder that cannot be made stops the run now (under MPI only rank 0 probes); and on every rank, no input inside
    it and no file in it that distnav did not write (:func:`~distnav.options.check_output_spares`)."""
    backend = getattr(args, "backend", "inprocess")
    if getattr(args, "ranks", None) is not None and backend != "mpi":
        raise UsageError(f"--ranks {args.ranks} applies only with --backend mpi (launched with mpiexec -n N)")
    if (getattr(args, "jobs", None) or 1) > 1 and backend == "mpi":
        raise UsageError(
            f"--jobs {args.jobs} applies only with the in-process backend (under MPI the ranks share the work)"
        )
    if backend == "mpi":
        from distnav._optional import require

        require("mpi4py.MPI", "mpi")
    check_repeated_inputs(args)  # one file twice in a list (--bias A A): options.py
    if getattr(args, "experiment", None) in EXPERIMENTS:  # sizes that are each allowed but not together
        getattr(load(args.experiment), "check_options", lambda _: None)(args)
    out = getattr(args, "out", None)
    if out is not None and probe_out:
        probe_output_folder(out)
    inputs = input_paths(v for k, v in vars(args).items() if k not in {"out", "func", "node_files"})
    node_files = getattr(args, "node_files", None)  # one node of a field network: a shared folder (options.py)
    if out is not None and node_files is not None:
        check_node_outputs(out, node_files(args), inputs)
    elif out is not None:  # nothing written over an input or over a file distnav did not write (options.py)
        check_output_spares(out, inputs)


#: Seconds a failing rank waits between writing its ``error on MPI rank R of N`` line and ``MPI_Abort``: the line is
#: in the stderr pipe at once (one unbuffered write), but mpiexec's proxy forwards it only when it next reads that
#: pipe, and the abort tears the job down; under heavy load the line was lost (issue 29 item 5). A failure is rare,
#: half a second is cheap. Stress-tested in tests/test_cli_mpi.py.
ABORT_GRACE_S = 0.5


def _error_line_then_abort(comm: Any, rank: int, exc: BaseException) -> int:
    """Write the failing rank's error line to file descriptor 2 (not ``sys.stderr``, which is muted on ranks other
    than 0), wait :data:`ABORT_GRACE_S`, then abort every rank with exit code 2 (a user error) or 1."""
    code = 2 if isinstance(exc, DistnavError) else 1
    line = f"error on MPI rank {rank} of {comm.Get_size()}: {type(exc).__name__}: {exc}\n"
    try:
        sys.stderr.flush()
    except (OSError, ValueError):
        pass
    os.write(2, line.encode("utf-8", "replace"))
    time.sleep(ABORT_GRACE_S)
    comm.Abort(code)
    return code  # pragma: no cover - Abort does not return


def _main_mpi(args: argparse.Namespace) -> int:
    """Run under MPI: one writer, one voice — rank 0 writes the files and prints (progress, warnings, results);
    the other ranks' stdout and stderr are muted (they run the same computation, so they would print the same
    lines N times). Any failure on any rank still writes ``error on MPI rank R of N: ...`` (straight to file
    descriptor 2) and aborts the whole job."""
    from distnav._optional import require
    from distnav.output import set_file_writer

    MPI = require("mpi4py.MPI", "mpi")
    rank = MPI.COMM_WORLD.Get_rank()
    if rank != 0:
        set_file_writer(False)
        sys.stdout = open(os.devnull, "w")  # noqa: SIM115 - lives for the whole process
        sys.stderr = open(os.devnull, "w")  # noqa: SIM115 - the error line goes to fd 2 directly
    try:
        check_arguments(args, probe_out=rank == 0)
        _check_mpi_launch(args)
        return _dispatch_recording(args)
    except BaseException as exc:  # noqa: BLE001 - every failure must end all ranks
        return _error_line_then_abort(MPI.COMM_WORLD, rank, exc)


def _dispatch_recording(args: argparse.Namespace) -> int:
    """:func:`_dispatch`, then (also after a failure) list what is now in ``--out`` as distnav's (on the writing
    rank), so a re-run into the same folder is allowed and a file put there by hand is not."""
    from distnav.output import is_file_writer

    try:
        return _dispatch(args)
    finally:
        out = getattr(args, "out", None)
        if out is not None and is_file_writer() and getattr(args, "node_files", None) is None:
            record_outputs(out)  # not by one node of a field network: the folder is shared, its files are its own


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


def _show_warning(
    message: Warning | str,
    category: type[Warning],
    filename: str,
    lineno: int,
    file: object = None,
    line: str | None = None,
) -> None:
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
    words = list(sys.argv[1:] if argv is None else argv)
    if all(w.startswith("-") for w in words):  # no command named: --help, --version or a usage error
        top = build_top_level_parser()
        if top is not None:
            top.parse_args(words)  # exits (help, version, or the error that a command is required)
    parser = build_parser(words)
    args = parser.parse_args(words)
    try:
        check_repeated_options(parser, words)  # --obs A --obs B: argparse keeps B alone (options.py)
    except UsageError as exc:
        print(_user_error(exc), file=sys.stderr)
        return 2
    if getattr(args, "backend", "inprocess") == "mpi":
        try:  # every rank fails alike here, before MPI starts
            check_arguments(args, probe_out=False)
        except DistnavError as exc:
            print(_user_error(exc), file=sys.stderr)
            return 2
        return _main_mpi(args)  # checks again inside, where a failure on one rank aborts them all
    try:
        check_arguments(args)
        return _dispatch_recording(args)
    except DistnavError as exc:
        print(_user_error(exc), file=sys.stderr)
        return 2
    except OSError as exc:  # a file that vanished or could not be written mid-run: say which, no traceback
        print(_user_error(exc), file=sys.stderr)
        return 2


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
