"""Lazy import of optional dependencies with an error that says which extra to install."""

from __future__ import annotations

import importlib
from types import ModuleType

from distnav.errors import MissingExtraError


def require(module: str, extra: str) -> ModuleType:
    """Import ``module`` or raise :class:`MissingExtraError` naming ``pip install 'distnav[extra]'``."""
    try:
        return importlib.import_module(module)
    except ImportError as exc:  # pragma: no cover - exercised only without the extra
        raise MissingExtraError(
            f"{module} is needed for this feature: pip install 'distnav[{extra}]' (or pip install {module})"
        ) from exc
