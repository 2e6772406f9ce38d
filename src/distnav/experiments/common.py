"""What every reproduction shares: output folder, backend, seeded randomness, progress, atomic writes, figures.

An experiment module ``distnav.experiments.<name>`` defines::

    NAME = "admm"                       # the CLI name: distnav reproduce admm
    TITLE = "Distributed least squares by ADMM (paper 000 Figs. 3-5)"
    def run(ctx: ExperimentContext) -> dict: ...   # writes figures + results.json, returns the results

and is listed in :data:`distnav.experiments.EXPERIMENTS`. ``ctx.quick`` selects the small variant that
``distnav demo`` runs. Only the root block (rank 0 under MPI) writes files; every write goes to a temporary
name first and is renamed on success, so a failed run leaves no half-written output. The writers themselves
(:func:`atomic_write_text`, :func:`atomic_write_json`, :func:`save_figure_file`, :func:`pyplot`, the rank-0 switch)
live in :mod:`distnav.output`, shared with :mod:`distnav.commands` (import them from there; :func:`pyplot` is
re-exported here for the experiments' figures).
"""

from __future__ import annotations

import argparse
import multiprocessing
import os
import time
from collections.abc import Callable, Iterable, Iterator, Sequence
from concurrent.futures import ProcessPoolExecutor
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any, TypeVar

import numpy as np

from distnav.errors import UsageError
from distnav.exchange import Exchange, FaultSchedule, make_exchange
from distnav.network.graph import Graph
from distnav.options import add_size_option, jobs_count
from distnav.output import atomic_write_json, atomic_write_text, pyplot, save_figure_file

if TYPE_CHECKING:
    from matplotlib.figure import Figure

T = TypeVar("T")
R = TypeVar("R")

__all__ = [
    "ExperimentContext",
    "Progress",
    "add_jobs_argument",
    "available_cores",
    "parallel_map",
    "pyplot",  # re-exported from distnav.output for the experiments' figures
]


def _noop(n: int = 1) -> None:
    return None


class Progress:
    """Minimal progress reporting: a rich progress bar when ``rich`` is installed and stderr is a terminal,
    otherwise one line per task start/finish. Silent when ``enabled`` is False (e.g. non-root MPI ranks)."""

    def __init__(self, enabled: bool = True) -> None:
        self.enabled = enabled

    @contextmanager
    def task(self, description: str, total: int | None = None) -> Iterator[Callable[[int], None]]:
        """Context manager yielding ``advance(n)``; prints timing when done."""
        if not self.enabled:
            yield _noop
            return
        import sys

        t0 = time.perf_counter()
        bar = None
        if sys.stderr.isatty() and total:
            try:
                from rich.progress import BarColumn, TimeElapsedColumn
                from rich.progress import Progress as RichProgress

                bar = RichProgress(
                    "[bold]{task.description}",
                    BarColumn(),
                    "{task.completed}/{task.total}",
                    TimeElapsedColumn(),
                    transient=True,
                )
            except ImportError:  # pragma: no cover
                bar = None
        if bar is not None:
            with bar:
                tid = bar.add_task(description, total=total)

                def advance(n: int = 1) -> None:
                    bar.advance(tid, n)

                yield advance
        else:
            print(f"  … {description}", file=sys.stderr, flush=True)
            yield _noop
        print(f"  ✓ {description} ({time.perf_counter() - t0:.1f} s)", file=sys.stderr, flush=True)

    def iterate(self, items: Iterable[T], description: str, total: int | None = None) -> Iterator[T]:
        """Yield ``items`` while advancing a task of ``total`` steps (``len(items)`` when not given)."""
        seq: Iterable[T] = items
        if total is None:
            seq = list(items)
            total = len(seq)
        with self.task(description, total) as advance:
            for it in seq:
                yield it
                advance(1)


def available_cores() -> int:
    """The CPU cores this process may run on (its affinity mask where the platform has one)."""
    try:
        return max(len(os.sched_getaffinity(0)), 1)
    except AttributeError:  # pragma: no cover - not Linux
        return max(os.cpu_count() or 1, 1)


def add_jobs_argument(parser: argparse.ArgumentParser) -> None:
    """``--jobs N``: worker processes for an experiment's independent runs (:meth:`ExperimentContext.workers`),
    at most ``options.jobs_count.maximum``."""
    add_size_option(
        parser,
        "--jobs",
        jobs_count,
        default=None,
        help="worker processes for the independent runs, the results do not depend on it (default: the available "
        "cores; 1: none)",
    )


def parallel_map(
    fn: Callable[[T], R], tasks: Sequence[T], jobs: int, advance: Callable[[int], None] = _noop
) -> list[R]:
    """``[fn(t) for t in tasks]``, in ``jobs`` worker processes when ``jobs > 1`` (and there is more than one task).

    The results come back in the order of ``tasks`` whatever the order the workers finish in, so a reduction over
    them is the same sum in the same order as the serial loop (bit-identical results). ``fn`` and the tasks must
    be picklable (module-level functions, plain data); each task must draw its own random numbers (seeded from
    the task), never from state shared between tasks. ``advance(1)`` is called as each result arrives. Workers
    are forked where the platform allows it (no re-import), else spawned. Inside a daemonic worker (``distnav demo
    --jobs N`` runs whole experiments in pool workers, which may not have children) the loop runs serially.
    """
    if jobs <= 1 or len(tasks) <= 1 or multiprocessing.current_process().daemon:
        out = []
        for t in tasks:
            out.append(fn(t))
            advance(1)
        return out
    method = "fork" if "fork" in multiprocessing.get_all_start_methods() else "spawn"
    with ProcessPoolExecutor(max_workers=min(jobs, len(tasks)), mp_context=multiprocessing.get_context(method)) as pool:
        out = []
        for r in pool.map(fn, tasks):
            out.append(r)
            advance(1)
        return out


@dataclass
class ExperimentContext:
    """Everything a reproduction needs besides its own parameters."""

    out_dir: Path
    quick: bool = False
    backend: str = "inprocess"
    seed: int = 0
    progress: Progress = field(default_factory=Progress)
    faults: FaultSchedule | None = None
    options: dict[str, Any] = field(default_factory=dict)
    figures: list[str] = field(default_factory=list)
    _root: bool | None = None

    def __post_init__(self) -> None:
        self.out_dir = Path(self.out_dir)

    def option(self, name: str, default: Any, *, minimum: float | None = None) -> Any:
        """The experiment option ``name`` (from ``--name``), or ``default`` when it was not given (``None``).

        A given value is never replaced by the default (``--epochs 0`` is not "the default"); below ``minimum`` it
        is refused with :class:`~distnav.errors.UsageError` (the CLI already refuses it when parsing)."""
        value = self.options.get(name)
        if value is None:
            return default
        if minimum is not None and value < minimum:
            raise UsageError(f"--{name.replace('_', '-')} must be at least {minimum:g}, got {value!r}")
        return value

    def workers(self) -> int:
        """Worker processes for independent runs: ``--jobs`` (default: the available cores); 1 under MPI (the
        ranks run every run in step) or with fault injection (the schedule lives in this process)."""
        jobs = int(self.option("jobs", available_cores(), minimum=1))
        return jobs if self.backend == "inprocess" and self.faults is None else 1

    def rng(self, stream: int = 0) -> np.random.Generator:
        """A generator seeded from ``(seed, stream)``: independent streams, reproducible runs."""
        return np.random.default_rng([self.seed, stream])

    def exchange(self, graph: Graph, faults: FaultSchedule | None = None) -> Exchange:
        """An exchange on ``graph`` for the context's backend."""
        ex = make_exchange(graph, backend=self.backend, faults=faults if faults is not None else self.faults)
        if self._root is None:
            self._root = ex.is_root
            if not self._root:
                self.progress.enabled = False
        return ex

    @property
    def is_root(self) -> bool:
        if self._root is None:
            if self.backend == "mpi":
                from distnav.exchange.mpi import world_rank  # lazy

                self._root = world_rank() == 0
            else:
                self._root = True
            if not self._root:
                self.progress.enabled = False
        return self._root

    def write_json(self, name: str, data: Any) -> Path:
        path = self.out_dir / name
        if self.is_root:
            atomic_write_json(path, data)
        return path

    def write_text(self, name: str, text: str) -> Path:
        path = self.out_dir / name
        if self.is_root:
            atomic_write_text(path, text)
        return path

    def save_figure(self, fig: Figure, name: str) -> str | None:
        """Save a matplotlib figure as ``out_dir/name`` (PNG, atomically) and close it; returns the file name."""
        import matplotlib.pyplot as plt

        if self.is_root:
            save_figure_file(fig, self.out_dir / name)
            self.figures.append(name)
        plt.close(fig)
        return name
