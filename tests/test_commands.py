"""The command line as a whole: the commands package, a light `import ogscene3d` / `ogscene3d --help`,
`ogscene3d config`, and the evaluation options shared by eval, eval-batch and run-batch --eval."""

from __future__ import annotations

import dataclasses
import importlib
import json
import subprocess
import sys

import pytest
import yaml

import ogscene3d
from ogscene3d import cli
from ogscene3d.commands import COMMAND_MODULES
from ogscene3d.config import Config, load_config
from ogscene3d.eval.options import EvalOptions

HEAVY = ("torch", "warp", "open3d", "viser", "cv2", "rerun")
COMMANDS = ["run", "eval", "live", "synth", "segment", "track", "graph", "run-batch", "eval-batch",
            "render-demo", "config"]  # fmt: skip


def _loaded_after(code: str) -> dict:
    """The heavy modules (and the count of ogscene3d's) that a fresh interpreter holds after ``code``."""
    probe = (
        f"{code}\nimport json, sys\n"
        f"print(json.dumps({{'heavy': [m for m in {HEAVY!r} if m in sys.modules], "
        "'ours': sum(m.startswith('ogscene3d') for m in sys.modules)}))"
    )
    out = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True, check=True).stdout
    return json.loads(out.strip().splitlines()[-1])


def test_import_ogscene3d_loads_no_torch_warp_or_open3d():
    loaded = _loaded_after("import ogscene3d")
    assert loaded["heavy"] == [] and loaded["ours"] <= 3, loaded


def test_help_builds_every_command_without_heavy_imports():
    loaded = _loaded_after("from ogscene3d import cli\ncli.build_parser()")
    assert loaded["heavy"] == [], loaded
    # and the real entry point answers
    res = subprocess.run([sys.executable, "-m", "ogscene3d.cli", "--help"], capture_output=True, text=True)
    assert res.returncode == 0
    for name in COMMANDS:
        assert name in res.stdout


@pytest.mark.parametrize("name", COMMANDS)
def test_each_command_has_help(name, capsys):
    with pytest.raises(SystemExit) as e:
        cli.main([name, "--help"])
    assert e.value.code == 0
    assert f"usage: ogscene3d {name}" in capsys.readouterr().out


def test_registry_modules_each_register_a_command():
    for module in COMMAND_MODULES:
        assert callable(importlib.import_module(module).add_parser), module


def test_public_names_stay_importable():
    from ogscene3d import Mapper, Segmentation, evaluate_run, rasterization  # noqa: F401

    assert "Segmentation" in ogscene3d.__all__
    for name in ogscene3d.__all__:
        assert getattr(ogscene3d, name) is not None, name
    for pkg in ("datasets", "eval", "graph", "mapping", "segmentation", "viewer"):
        module = importlib.import_module(f"ogscene3d.{pkg}")
        for name in module.__all__:
            assert getattr(module, name) is not None, f"ogscene3d.{pkg}.{name}"
    with pytest.raises(AttributeError, match="no attribute 'nope'"):
        ogscene3d.nope  # noqa: B018


# ------------------------------------------------------------------------------------------ ogscene3d config
def test_config_yaml_lists_every_key_and_loads_back(tmp_path, capsys):
    assert cli.main(["config"]) == 0
    text = capsys.readouterr().out
    path = tmp_path / "all.yaml"
    path.write_text(text)
    assert load_config(path) == Config()
    assert "# paper tau_p: overlap p(m) below which a segment is a new object [in [0, 1]]" in text
    assert "[one of naive, local, local+global, full]" in text  # choices from the Literal


def test_config_prefix_table_and_values(capsys):
    args = ["config", "mapping.association.tau_", "--format", "table"]
    args += ["--set", "mapping.association.tau_p=0.2"]
    assert cli.main(args) == 0
    lines = capsys.readouterr().out.splitlines()
    keys = [ln.split()[0] for ln in lines[1:] if ln and not ln.startswith(" ")]
    assert keys == ["mapping.association.tau_valid", "mapping.association.tau_p"]
    tau_p = next(ln for ln in lines if ln.startswith("mapping.association.tau_p "))
    assert tau_p.split()[1] == "0.2" and "in [0, 1]" in tau_p
    assert cli.main(["config", "mapping.nope"]) == 2
    assert "no config key starts with 'mapping.nope'" in capsys.readouterr().err


def test_config_yaml_of_a_prefix_is_a_partial_config(capsys):
    assert cli.main(["config", "graph.relations.kind"]) == 0
    assert yaml.safe_load(capsys.readouterr().out) == {"graph": {"relations": {"kind": "geometric"}}}


# --------------------------------------------------------------------------------------- evaluation options
def _flags(command: str) -> set[str]:
    parser = cli.build_parser()
    sub = next(a for a in parser._actions if a.dest == "command")
    return {s for a in sub.choices[command]._actions for s in a.option_strings}


def test_eval_options_are_the_same_on_every_evaluating_command():
    wanted = {f.metadata["flag"] for f in dataclasses.fields(EvalOptions)}
    assert {"--assoc-radius", "--min-node-iou", "--view-frames", "--mapping-frames"} <= wanted
    for command in ("eval", "eval-batch", "run-batch"):
        missing = wanted - _flags(command)
        assert not missing, f"{command} lacks {sorted(missing)}"  # before: eval-batch lacked four


def test_eval_options_from_the_command_line():
    from ogscene3d.eval.options import eval_options_from_args

    parser = cli.build_parser()
    args = parser.parse_args(["eval-batch", "out", "--protocol", "both", "--ignore", "wall, floor",
                              "--assoc-radius", "0", "--view-frames", "1,3", "--no-plots"])  # fmt: skip
    opts = eval_options_from_args(args)
    assert opts.protocols == ("hovsg", "conceptgraphs") and tuple(opts.ignore) == ("wall", "floor")
    assert opts.assoc_radius is None and list(opts.view_frames) == [1, 3] and not opts.plots
    assert opts.num_views == 0  # eval-batch renders no view unless asked
    assert eval_options_from_args(parser.parse_args(["eval", "run"])).num_views == 3  # eval's own default
    args = parser.parse_args(["eval-batch", "out", "--held-out"])
    with pytest.raises(ogscene3d.errors.ConfigError, match="--held-out needs views to score"):
        eval_options_from_args(args)


def test_evaluate_run_takes_the_options_by_keyword(tmp_path):
    from ogscene3d.eval import evaluate_run

    with pytest.raises(TypeError, match="protocol"):
        evaluate_run(tmp_path, tmp_path, protocol="hovsg")  # the field is `protocols`
    with pytest.raises(ValueError, match="k must be >= 1"):
        evaluate_run(tmp_path, tmp_path, EvalOptions(k=0))
