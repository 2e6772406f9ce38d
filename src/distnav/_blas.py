"""One BLAS thread for a block of small dense linear algebra (utility layer, like :mod:`distnav._sparse`).

The solvers factorise many small matrices (UWB banded Cholesky, Kalman pseudo-inverses, MDS starts); on a loaded
2-core machine OpenBLAS's worker threads make them many times dearer in CPU (measured: a 290×290 banded Cholesky
47 ms instead of 0.4 ms; a p ≲ 50 ``eigh`` 15–60×). :func:`single_threaded_blas` sets the thread count of the
OpenBLAS copies numpy and scipy load to one for a block and restores it after; a no-op where OpenBLAS is not found.
Moved here from :mod:`distnav.algorithms.ranging.lm` (which re-exports it) when the Kalman kernel came to need it too.
"""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager
from typing import Any

__all__ = ["single_threaded_blas"]


def _openblas_handles() -> list[tuple[Any, Any]]:
    """(set, get) thread-count functions of the OpenBLAS copies loaded by numpy and scipy (empty if none)."""
    import ctypes
    import glob
    import os

    out: list[tuple[Any, Any]] = []
    for pkg in ("numpy", "scipy"):
        try:
            mod = __import__(pkg)
        except ImportError:  # pragma: no cover
            continue
        libdir = os.path.join(os.path.dirname(os.path.dirname(mod.__file__ or "")), f"{pkg}.libs")
        for path in glob.glob(os.path.join(libdir, "libscipy_openblas*.so*")):
            try:
                lib = ctypes.CDLL(path)
            except OSError:  # pragma: no cover
                continue
            for suffix in ("64_", ""):
                setter = getattr(lib, f"scipy_openblas_set_num_threads{suffix}", None)
                getter = getattr(lib, f"scipy_openblas_get_num_threads{suffix}", None)
                if setter is not None and getter is not None:
                    setter.argtypes = [ctypes.c_int]
                    getter.restype = ctypes.c_int
                    out.append((setter, getter))
                    break
    return out


_BLAS: list[tuple[Any, Any]] | None = None


@contextmanager
def single_threaded_blas() -> Iterator[None]:
    """Run the block with OpenBLAS limited to one thread (restored afterwards).

    The UWB solvers factorise many small matrices; on a loaded 2-core machine OpenBLAS's worker threads make a
    290×290 banded Cholesky 100× slower (measured: 47 ms instead of 0.4 ms). A no-op where OpenBLAS is not found.
    """
    global _BLAS
    if _BLAS is None:
        try:
            _BLAS = _openblas_handles()
        except Exception:  # pragma: no cover - never let a speed tweak break a solve
            _BLAS = []
    saved = []
    for setter, getter in _BLAS:
        try:
            saved.append((setter, int(getter())))
            setter(1)
        except Exception:  # pragma: no cover
            pass
    try:
        yield
    finally:
        for setter, n in saved:
            setter(n)
