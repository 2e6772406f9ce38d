"""What every reproduction shares: output folder, backend, seeded randomness, progress, atomic writes, figures.

An experiment module ``distnav.experiments.<name>`` defines::

    NAME = "admm"                       # the CLI name: distnav reproduce admm
    TITLE = "Distributed least squares by ADMM (paper 000 Figs. 3-5)"
    def run(ctx: ExperimentContext) -> dict: ...   # writes figures + results.json, returns the results

and is listed in :data:`distnav.experiments.EXPERIMENTS`. ``ctx.quick`` selects the small variant that
``distnav demo`` runs. Only the root block (rank 0 under MPI) writes files; every write goes to a temporary
name first and is renamed on success, so a failed run leaves no half-written output.
"""

from __future__ import annotations

import json
import os
import tempfile
import time
from collections.abc import Callable, Iterable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from distnav.exchange import Exchange, FaultSchedule, make_exchange
from distnav.network.graph import Graph

__all__ = [
    "ExperimentContext",
    "Progress",
    "to_jsonable",
    "atomic_write_text",
    "atomic_write_json",
    "save_figure_file",
    "set_file_writer",
    "is_file_writer",
]


def to_jsonable(obj: Any) -> Any:
    """Convert numpy scalars/arrays (and nested containers) to plain JSON types; NaN → None."""
    if isinstance(obj, dict):
        return {str(k): to_jsonable(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [to_jsonable(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return to_jsonable(obj.tolist())
    if isinstance(obj, (np.bool_, bool)):
        return bool(obj)
    if isinstance(obj, (np.integer,)):
        return int(obj)
    if isinstance(obj, (np.floating, float)):
        v = float(obj)
        return None if not np.isfinite(v) else v
    if isinstance(obj, Path):
        return str(obj)
    return obj


_FILE_WRITER = True


def set_file_writer(enabled: bool) -> None:
    """Under MPI only rank 0 writes: the CLI calls ``set_file_writer(False)`` on every other rank, which turns
    :func:`atomic_write_text`, :func:`atomic_write_json` and :func:`save_figure_file` into no-ops there."""
    global _FILE_WRITER
    _FILE_WRITER = bool(enabled)


def is_file_writer() -> bool:
    return _FILE_WRITER


def save_figure_file(fig: Any, path: Path, *, dpi: int = 110) -> None:
    """Save a matplotlib figure atomically as PNG (no-op on non-writing MPI ranks) and close it."""
    import matplotlib.pyplot as plt

    if _FILE_WRITER:
        path = Path(path)
        path.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".png", dir=path.parent)
        os.close(fd)
        try:
            fig.savefig(tmp, dpi=dpi, bbox_inches="tight")
            os.replace(tmp, path)
        except BaseException:
            Path(tmp).unlink(missing_ok=True)
            raise
    plt.close(fig)


def atomic_write_text(path: Path, text: str) -> None:
    """Write ``text`` to ``path`` via a temporary file in the same folder and an atomic rename.

    A no-op on MPI ranks other than 0 (see :func:`set_file_writer`)."""
    if not _FILE_WRITER:
        return
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    try:
        with os.fdopen(fd, "w", encoding="utf-8") as fh:
            fh.write(text)
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def atomic_write_json(path: Path, data: Any) -> None:
    atomic_write_text(path, json.dumps(to_jsonable(data), indent=2) + "\n")


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

                bar = RichProgress("[bold]{task.description}", BarColumn(), "{task.completed}/{task.total}",
                                   TimeElapsedColumn(), transient=True)
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

    def iterate(self, items: Iterable[Any], description: str, total: int | None = None) -> Iterator[Any]:
        items = list(items) if total is None else items
        n = total if total is not None else len(items)  # type: ignore[arg-type]
        with self.task(description, n) as advance:
            for it in items:
                yield it
                advance(1)


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

    def save_figure(self, fig: Any, name: str) -> str | None:
        """Save a matplotlib figure as ``out_dir/name`` (PNG, atomically) and close it; returns the file name."""
        import matplotlib.pyplot as plt

        if self.is_root:
            save_figure_file(fig, self.out_dir / name)
            self.figures.append(name)
        plt.close(fig)
        return name


def pyplot() -> Any:
    """matplotlib.pyplot with the non-interactive Agg backend (needs the ``plot`` extra)."""
    from distnav._optional import require

    mpl = require("matplotlib", "plot")
    mpl.use("Agg")
    import matplotlib.pyplot as plt

    return plt
