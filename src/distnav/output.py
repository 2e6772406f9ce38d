"""Writing output files: atomic writes, JSON conversion, figures, and the rank-0 writer switch.

Used by :mod:`distnav.experiments`, :mod:`distnav.commands` and the CLI, and sitting just below them in the layers
(above :mod:`distnav.models`; see docs/DEVELOPING.md): it imports only the standard library and numpy (matplotlib
lazily, in :func:`pyplot`). The library layers (network, exchange, algorithms, models) compute and return; they
neither write files nor plot, so they do not import it.

Every write goes to a temporary name in the target folder first and is renamed on success, so a failed run leaves
no half-written file; the file gets the mode the umask gives (0644 under the usual 022), not the temporary's 0600.
Under MPI only rank 0 writes: the CLI calls :func:`set_file_writer(False) <set_file_writer>` on every other rank,
which turns :func:`atomic_write_text`, :func:`atomic_write_json` and :func:`save_figure_file` into no-ops there.
"""

from __future__ import annotations

import json
import os
import tempfile
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

if TYPE_CHECKING:
    from matplotlib.figure import Figure

__all__ = [
    "to_jsonable",
    "atomic_write_text",
    "atomic_write_json",
    "save_figure_file",
    "set_file_writer",
    "is_file_writer",
    "pyplot",
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
    """Switch file writing on or off for this process (the CLI switches it off on MPI ranks other than 0)."""
    global _FILE_WRITER
    _FILE_WRITER = bool(enabled)


def is_file_writer() -> bool:
    """Whether this process writes files (False on MPI ranks other than 0)."""
    return _FILE_WRITER


def _umask() -> int:
    mask = os.umask(0o022)  # reading the umask means setting it: put it straight back
    os.umask(mask)
    return mask


def _temporary(path: Path, suffix: str) -> Path:
    """A fresh temporary file next to ``path`` (same folder, so the final rename is atomic).

    :func:`tempfile.mkstemp` creates it mode 0600; it gets the mode a plain ``open(path, "w")`` would give
    (0666 less the umask), so results can be shared as the user's umask says."""
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=suffix, dir=path.parent)
    try:
        os.fchmod(fd, 0o666 & ~_umask())
    finally:
        os.close(fd)
    return Path(tmp)


def save_figure_file(fig: Figure, path: str | Path, *, dpi: int = 110) -> None:
    """Save a matplotlib figure atomically as PNG (no-op on non-writing MPI ranks) and close it (also on failure)."""
    import matplotlib.pyplot as plt

    try:
        if _FILE_WRITER:
            target = Path(path)
            tmp = _temporary(target, ".png")
            try:
                fig.savefig(tmp, dpi=dpi, bbox_inches="tight")
                os.replace(tmp, target)
            except BaseException:
                tmp.unlink(missing_ok=True)
                raise
    finally:
        plt.close(fig)


def atomic_write_text(path: str | Path, text: str) -> None:
    """Write ``text`` (UTF-8) to ``path`` via a temporary file in the same folder and an atomic rename.

    A no-op on MPI ranks other than 0 (see :func:`set_file_writer`)."""
    if not _FILE_WRITER:
        return
    target = Path(path)
    tmp = _temporary(target, ".tmp")
    try:
        tmp.write_text(text, encoding="utf-8")
        os.replace(tmp, target)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise


def atomic_write_json(path: str | Path, data: Any) -> None:
    """:func:`to_jsonable` of ``data`` as indented JSON, written with :func:`atomic_write_text`."""
    atomic_write_text(path, json.dumps(to_jsonable(data), indent=2) + "\n")


def pyplot() -> Any:
    """matplotlib.pyplot with the non-interactive Agg backend (needs the ``plot`` extra)."""
    from distnav._optional import require

    mpl = require("matplotlib", "plot")
    mpl.use("Agg")
    import matplotlib.pyplot as plt

    return plt
