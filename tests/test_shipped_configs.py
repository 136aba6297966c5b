"""The configs shipped in the package: ``load_config("replica")`` by bare name, from the source tree and
from a wheel."""

from __future__ import annotations

import dataclasses
import os
import shutil
import subprocess
import sys
import zipfile
from pathlib import Path

import pytest

from ogscene3d.config import load_config
from ogscene3d.errors import ConfigError
from ogscene3d.shipped_configs import resolve_config_path, shipped_configs

ROOT = Path(__file__).resolve().parents[1]
CONFIGS = sorted(p.name for p in (ROOT / "configs").glob("*.yaml"))


def test_every_config_of_the_repo_is_shipped_by_name():
    assert CONFIGS, "configs/*.yaml not found"
    assert sorted(f"{name}.yaml" for name in shipped_configs()) == CONFIGS


@pytest.mark.parametrize("name", ["replica", "replica.yaml", "scannet", "synthetic", "tum"])
def test_a_bare_name_loads_the_shipped_config(name, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)  # not the repository: the name alone must find the file
    stem = name.removesuffix(".yaml")
    expected = load_config(ROOT / "configs" / f"{stem}.yaml")
    assert dataclasses.asdict(load_config(name)) == dataclasses.asdict(expected)
    assert dataclasses.asdict(load_config(name)) != dataclasses.asdict(load_config(None))


def test_a_file_that_exists_wins_over_a_shipped_name(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    Path("replica").write_text("mapping:\n  opt_iters: 7\n")
    assert resolve_config_path("replica") == Path("replica")
    assert load_config("replica").mapping.optimize.iters == 7


def test_an_unknown_name_or_a_missing_path_names_the_shipped_configs(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    with pytest.raises(ConfigError, match=r"'replika' does not exist .*replica, .*synthetic"):
        load_config("replika")
    # a path with a folder part is never taken for a name
    with pytest.raises(ConfigError, match="does not exist"):
        load_config("elsewhere/replica.yaml")


def _build_wheel(tmp_path: Path) -> Path:
    """The project's wheel, built offline from a copy of the sources (a build writes into its source tree)."""
    try:
        import setuptools
    except ImportError:
        pytest.skip("setuptools is not installed")
    major, minor = (int(x) for x in setuptools.__version__.split(".")[:2])
    has_bdist_wheel = (major, minor) >= (70, 1)
    if not has_bdist_wheel:
        try:
            import wheel  # noqa: F401
        except ImportError:
            pytest.skip(f"setuptools {setuptools.__version__} without the wheel package cannot build a wheel")
    src = tmp_path / "project"
    src.mkdir()
    for name in ("pyproject.toml", "README.md", "LICENSE"):
        if (ROOT / name).is_file():
            shutil.copy2(ROOT / name, src / name)
    ignore = shutil.ignore_patterns("__pycache__", "*.egg-info")
    for name in ("src", "kernels", "configs"):
        shutil.copytree(ROOT / name, src / name, ignore=ignore)
    out = tmp_path / "wheel"
    cmd = [sys.executable, "-m", "pip", "wheel", "--no-deps", "--no-build-isolation", "-q", "-w", str(out)]
    cmd.append(str(src))
    proc = subprocess.run(cmd, capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    (whl,) = out.glob("ogscene3d-*.whl")
    return whl


def test_the_wheel_ships_the_configs_and_load_config_finds_them_by_name(tmp_path):
    whl = _build_wheel(tmp_path)
    names = zipfile.ZipFile(whl).namelist()
    assert sorted(n.rsplit("/", 1)[1] for n in names if n.startswith("ogscene3d/configs/")) == CONFIGS
    assert any(n.endswith(".dist-info/licenses/LICENSE") or n.endswith(".dist-info/LICENSE") for n in names)

    site = tmp_path / "site"
    zipfile.ZipFile(whl).extractall(site)
    # The unpacked wheel comes first on sys.path, before this checkout's (editable) install; run from a folder
    # without configs/ so that only the wheel's files can answer.
    probe = (
        "import ogscene3d, ogscene3d.shipped_configs as s, dataclasses as d\n"
        "from ogscene3d.config import load_config\n"
        f"assert ogscene3d.__file__.startswith({str(site)!r}), ogscene3d.__file__\n"
        "files = s.shipped_configs()\n"
        f"assert all(str(p).startswith({str(site)!r}) for p in files.values()), files\n"
        "print(sorted(files), load_config('replica').mapping.init.pixels_per_gaussian)\n"
    )
    env = {**os.environ, "PYTHONPATH": str(site)}
    run_dir = tmp_path / "elsewhere"
    run_dir.mkdir()
    proc = subprocess.run(
        [sys.executable, "-c", probe], cwd=run_dir, env=env, capture_output=True, text=True, timeout=300
    )
    assert proc.returncode == 0, proc.stdout + proc.stderr
    expected = load_config(ROOT / "configs" / "replica.yaml").mapping.init.pixels_per_gaussian
    assert proc.stdout.strip().endswith(str(expected)), proc.stdout
    assert all(c.removesuffix(".yaml") in proc.stdout for c in CONFIGS)
