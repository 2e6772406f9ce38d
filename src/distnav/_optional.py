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


class LazyModule(ModuleType):
    """Stands for the module ``name`` and imports it when one of its attributes is first read; its namespace is
    then copied in, so later reads are plain attribute reads. For heavy dependencies that an import of distnav
    should not pay for before they are used (``scipy.sparse`` is half the start-up of an MPI job:
    docs/scale.md). Modules bind it under ``if not TYPE_CHECKING`` so the type checker sees the real module."""

    def __getattr__(self, attr: str) -> object:
        if attr.startswith("__") and attr.endswith("__"):  # introspection (copy, pickle, help) imports nothing
            raise AttributeError(attr)
        module = importlib.import_module(self.__name__)
        self.__dict__.update(module.__dict__)
        return getattr(module, attr)


def lazy(name: str) -> ModuleType:
    """A :class:`LazyModule` for ``name`` (imported on first attribute access)."""
    return LazyModule(name)
