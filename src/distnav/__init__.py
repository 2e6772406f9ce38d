"""distnav: distributed estimation over sensor networks.

Layers (imports point downwards only): ``network`` → ``exchange`` → ``algorithms`` → ``models`` →
(``output``) → ``experiments`` | ``commands`` → ``cli``, with ``errors``, ``_optional`` and ``typing`` usable by
all. See docs/DEVELOPING.md (checked by tests/test_layers.py).
"""

from __future__ import annotations

__version__ = "0.3.0"

from distnav._threads import one_blas_thread_under_mpi  # noqa: E402

one_blas_thread_under_mpi()  # before any distnav module imports numpy (docs/scale.md, "Start-up")

from distnav import errors  # noqa: E402
from distnav.errors import *  # noqa: E402, F403 (the error types, listed once: distnav.errors.__all__)

__all__ = ["__version__"]
__all__ += errors.__all__
