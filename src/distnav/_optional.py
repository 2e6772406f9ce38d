"""Lazy import of optional dependencies with an error that names a pip command that works.

distnav is not on the package index (the index's ``distnav`` is an unrelated project, and ``distnav-estimation``
is not published), so ``pip install 'distnav-estimation[mpi]'`` fails. A missing extra is therefore named by the
packages it installs, which are on the index (``pip install 'mpi4py>=4.0' 'mpich>=4.1'``), and by the command that
installs the extra from a clone of the repository (``pip install '.[mpi]'``).
"""

from __future__ import annotations

import importlib
from types import ModuleType
from typing import TYPE_CHECKING

from distnav.errors import MissingExtraError

__all__ = ["DISTRIBUTION", "EXTRAS", "LazyModule", "install_hint", "lazy", "require", "scipy_sparse"]

DISTRIBUTION = "distnav-estimation"
"""The name distnav is installed under (``pip install .`` in a clone, or the wheel ``python -m build`` makes); the
import package is ``distnav``."""

#: What each extra installs: the same lists as ``[project.optional-dependencies]`` in pyproject.toml (a test holds
#: the two equal). Kept here so the hint needs no package metadata (an editable checkout without it still works).
EXTRAS: dict[str, tuple[str, ...]] = {
    "plot": ("matplotlib>=3.8",),
    "graph": ("networkx>=3.2",),
    "gnss": ("georinex>=1.16", "hatanaka>=2.8", "xarray>=2023.1"),
    "mpi": ("mpi4py>=4.0", "mpich>=4.1"),
    "progress": ("rich>=13",),
    "field": ("pyzmq>=26", "tomli-w>=1.0"),
}


def install_hint(extra: str) -> str:
    """The pip commands that install ``extra``: its packages from the index, or the extra from a clone, e.g.
    ``pip install 'mpi4py>=4.0' 'mpich>=4.1' (the mpi extra; in a distnav clone: pip install '.[mpi]')``."""
    packages = " ".join(f"'{p}'" for p in EXTRAS.get(extra, ()))
    clone = f"in a distnav clone: pip install '.[{extra}]'"
    return f"pip install {packages} (the {extra} extra; {clone})" if packages else f"{clone}"


def require(module: str, extra: str) -> ModuleType:
    """Import ``module`` or raise :class:`MissingExtraError` naming :func:`install_hint` of ``extra``.

    The message also names the import error itself (a missing shared library looks different from a missing
    package)."""
    try:
        return importlib.import_module(module)
    except ImportError as exc:
        raise MissingExtraError(
            f"{module} is needed for this feature and could not be imported ({exc}): {install_hint(extra)}"
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


if TYPE_CHECKING:
    import scipy.sparse as scipy_sparse
else:  # imported on first use (start-up of an MPI job): one lazy module for every layer that builds sparse matrices
    scipy_sparse = lazy("scipy.sparse")
