"""Lazy import of optional dependencies with an error that says which extra to install."""

from __future__ import annotations

import importlib
from types import ModuleType

from distnav.errors import MissingExtraError

DISTRIBUTION = "distnav-estimation"
"""The name distnav is installed under (``pip install distnav-estimation``); the import package is ``distnav``."""


def install_hint(extra: str) -> str:
    """``pip install 'distnav-estimation[extra]'``: the command that installs an extra."""
    return f"pip install '{DISTRIBUTION}[{extra}]'"


def require(module: str, extra: str) -> ModuleType:
    """Import ``module`` or raise :class:`MissingExtraError` naming ``pip install 'distnav-estimation[extra]'``.

    The message also names the pip package of ``module``'s top-level package (``mpi4py`` for ``mpi4py.MPI``) and
    the import error itself (a missing shared library looks different from a missing package)."""
    try:
        return importlib.import_module(module)
    except ImportError as exc:
        package = module.split(".", 1)[0]
        raise MissingExtraError(
            f"{module} is needed for this feature and could not be imported ({exc}): "
            f"{install_hint(extra)} (or pip install {package})"
        ) from exc
