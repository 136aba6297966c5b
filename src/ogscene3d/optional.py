"""Imports of optional dependencies (the extras in pyproject.toml), failing with the command that installs
them."""

from __future__ import annotations

import importlib
from types import ModuleType

from .errors import ConfigError


def require(module: str, extra: str, what: str) -> ModuleType:
    """``import module``, or a :class:`ConfigError` saying that ``what`` needs ``pip install
    "ogscene3d[extra]"``."""
    try:
        return importlib.import_module(module)
    except ImportError as e:
        raise ConfigError(
            f"{what} needs the Python package {module.split('.')[0]!r} ({e}): "
            f'pip install "ogscene3d[{extra}]"'
        ) from e
