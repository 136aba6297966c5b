"""The YAML configs shipped inside the package (``configs/*.yaml`` of the source tree, ``ogscene3d/configs``
in a wheel), found by bare name: ``load_config("replica")`` reads ``replica.yaml``.

A path that exists always wins over a shipped name, so a local file called ``replica`` is read as given.
"""

from __future__ import annotations

from importlib import resources
from pathlib import Path

CONFIG_SUFFIX = ".yaml"

# setuptools' editable installs do not resolve ``ogscene3d.configs`` (a data folder with no __init__.py mapped
# under a regular package), nor do ones made before it was mapped; in a source checkout the same files sit in
# ``configs/`` at the repository root, two levels above this package.
_SOURCE_TREE_CONFIGS = Path(__file__).resolve().parents[2] / "configs"


def shipped_configs() -> dict[str, Path]:
    """The shipped configs by name (``{"replica": .../replica.yaml, ...}``)."""
    try:
        entries = list(resources.files("ogscene3d.configs").iterdir())
    except (ModuleNotFoundError, FileNotFoundError, NotADirectoryError):
        entries = []
    if not entries and _SOURCE_TREE_CONFIGS.is_dir():
        entries = list(_SOURCE_TREE_CONFIGS.iterdir())
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
