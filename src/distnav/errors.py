"""Exception types of distnav.

Every error a user can trigger with bad input derives from :class:`DistnavError` *and* from the
builtin it specialises (mostly :class:`ValueError`), so ``except ValueError`` keeps working.
"""

from __future__ import annotations

__all__ = [
    "DistnavError",
    "GraphError",
    "WeightsError",
    "ExchangeError",
    "ModelError",
    "DataFileError",
    "MissingExtraError",
    "UsageError",
]


class DistnavError(Exception):
    """Base class of every distnav error."""


class GraphError(DistnavError, ValueError):
    """A communication graph is malformed or not connected."""


class WeightsError(DistnavError, ValueError):
    """A consensus weight matrix is not usable (wrong sparsity, negative, not stochastic...)."""


class ExchangeError(DistnavError, ValueError):
    """A message round was called with arrays of the wrong shape, or a fault schedule is invalid."""


class ModelError(DistnavError, ValueError):
    """An estimation problem is malformed or not determined (rank deficiency, bad shapes...)."""


class DataFileError(DistnavError, ValueError):
    """A data file could not be read; the message names the file and, where known, the line."""


class MissingExtraError(DistnavError, ImportError):
    """An optional dependency is missing; the message names the pip command that installs it
    (:func:`distnav._optional.install_hint`)."""


class UsageError(DistnavError, ValueError):
    """A command-line option, argument or output path is not usable (the CLI's exit code 2)."""
