"""The YAML configs shipped inside the package (``configs/*.yaml`` of the source tree, ``ogscene3d/configs``
in a wheel), found by bare name: ``load_config("replica")`` reads ``replica.yaml``.

A path that exists always wins over a shipped name, so a local file called ``replica`` is read as given.
"""

from __future__ import annotations

import importlib
from pathlib import Path

CONFIG_SUFFIX = ".yaml"


def shipped_configs() -> dict[str, Path]:
    """The shipped configs by name (``{"replica": .../replica.yaml, ...}``)."""
    # ``ogscene3d.configs`` is a folder without __init__.py (see ``_source_tree``): its files are those of
    # the folders on its ``__path__``.
    try:
        folders = list(importlib.import_module("ogscene3d.configs").__path__)
    except ModuleNotFoundError:
        folders = []
    entries = [e for folder in folders if Path(folder).is_dir() for e in Path(folder).iterdir()]
    return {
        e.name[: -len(CONFIG_SUFFIX)]: Path(str(e))
        for e in sorted(entries, key=lambda e: e.name)
        if e.name.endswith(CONFIG_SUFFIX) and e.is_file()
    }


def resolve_config_path(path: str | Path) -> Path:
    """``path`` itself when it is a file, else the shipped config that a bare name (``replica`` or
    ``replica.yaml``, no folder part) names; otherwise ``path`` unchanged, which the caller reports."""
    p = Path(path)
    if p.is_file() or p.parent != Path("."):
        return p
    name = p.name[: -len(CONFIG_SUFFIX)] if p.name.endswith(CONFIG_SUFFIX) else p.name
    return shipped_configs().get(name, p)
