"""The runnable examples' command lines: a second run with other scene arguments, and early argument errors.

The examples are loaded from their files; mapping and the viewer are stubbed, since these tests are about
what happens before them (the scene folder each run generates into, the checks of the arguments).
"""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path

import pytest

EXAMPLES = Path(__file__).resolve().parents[1] / "examples"


def load_example(name: str):
    spec = importlib.util.spec_from_file_location(f"example_{name}", EXAMPLES / f"{name}.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


class _Stop(Exception):
    pass


def test_synthetic_example_reruns_with_other_frames_and_size(tmp_path, monkeypatch):
    mod = load_example("synthetic")
    scenes = []

    def fake_ablation(cfg, scene, gt, out, ablations, device=None):
        scenes.append(Path(scene))
        assert Path(gt).is_dir() and ablations == ["naive"]
        return {}

    monkeypatch.setattr(mod, "run_ablation", fake_ablation)
    monkeypatch.setattr(mod, "format_ablation", lambda res: "table")
    out = tmp_path / "ex"
    for frames, size in (("2", "16x12"), ("3", "16x12"), ("2", "24x16")):
        argv = ["synthetic.py", "--out", str(out), "--frames", frames, "--size", size, "--ablations", "naive"]
        monkeypatch.setattr(sys, "argv", [*argv, "--device", "cpu"])
        mod.main()  # before: the second run refused the folder the first one's scene was in
    assert len(set(scenes)) == 3
    assert len(list((scenes[1] / "results").glob("frame*.jpg"))) == 3


@pytest.mark.parametrize(
    "args, message",
    [
        (["--ablations", "naive,lokal"], "--ablations: unknown ['lokal']"),
        (["--size", "160by120"], "argument --size: expected WxH"),
    ],
)
def test_synthetic_example_checks_arguments_before_generating(tmp_path, monkeypatch, capsys, args, message):
    mod = load_example("synthetic")
    monkeypatch.setattr(mod, "make_synthetic_scene", lambda *a, **k: pytest.fail("scene generated"))
    monkeypatch.setattr(sys, "argv", ["synthetic.py", "--out", str(tmp_path / "ex"), *args])
    with pytest.raises(SystemExit) as e:
        mod.main()
    err = capsys.readouterr().err
    assert e.value.code == 2 and message in err and "Traceback" not in err


def test_live_example_reruns_with_other_frames(tmp_path, monkeypatch):
    mod = load_example("live_synthetic")
    scenes = []

    def stop_after_scene(scene, config=None):
        scenes.append(Path(scene))
        raise _Stop

    monkeypatch.setattr(mod, "open_dataset", stop_after_scene)
    monkeypatch.chdir(tmp_path)  # the default scene folder is relative
    for frames in ("2", "3"):
        monkeypatch.setattr(sys, "argv", ["live_synthetic.py", "--frames", frames, "--device", "cpu"])
        with pytest.raises(_Stop):
            mod.main()  # before: the second run refused outputs/example-live-synthetic
    assert scenes[0] != scenes[1]
    assert len(list((tmp_path / scenes[1] / "results").glob("frame*.jpg"))) == 3
    # a --scene given by hand that holds other frames: --force regenerates it (the error said so)
    argv = ["live_synthetic.py", "--frames", "2", "--scene", str(scenes[1]), "--force"]
    monkeypatch.setattr(sys, "argv", argv)
    with pytest.raises(_Stop):
        mod.main()
    assert len(list((tmp_path / scenes[1] / "results").glob("frame*.jpg"))) == 2
