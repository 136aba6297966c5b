"""Clean errors and tidy output of small CLI commands: render-demo's argument checks, the batch footer."""

from __future__ import annotations

import cv2
import pytest

from ogscene3d.cli import main
from ogscene3d.commands.batch import protocol_line
from ogscene3d.errors import ConfigError
from ogscene3d.rendering import render_demo


@pytest.mark.parametrize(
    "args, message",
    [
        (["--out", "{tmp}/rd"], "is not an image file name OpenCV can write"),
        (["--views", "0"], "argument --views: expected an integer >= 1, got 0"),
        (["--size", "0x0"], "argument --size: width and height must be >= 1"),
        (["--size", "big"], "argument --size: expected WxH"),
        (["--gaussians", "-3"], "argument --gaussians: expected an integer >= 1"),
    ],
)
def test_render_demo_rejects_bad_arguments(tmp_path, capsys, args, message):
    args = [a.format(tmp=tmp_path) for a in args]
    with pytest.raises(SystemExit) as e:
        main(["render-demo", *args])
    err = capsys.readouterr().err
    assert e.value.code == 2 and message in err and "Traceback" not in err


def test_render_demo_library_checks_and_a_tiny_render(tmp_path, capsys):
    with pytest.raises(ConfigError, match="out='.*rd' is not an image file"):
        render_demo(tmp_path / "rd", 50, 16, 12, 1, "cpu")
    with pytest.raises(ConfigError, match="views must be an integer >= 1, got 0"):
        render_demo(tmp_path / "rd.png", 50, 16, 12, 0, "cpu")
    out = tmp_path / "rd.png"
    assert main(["render-demo", "--out", str(out), "--gaussians", "200", "--size", "16x12", "--views", "2",
                 "--device", "cpu"]) == 0  # fmt: skip
    assert f"wrote {out}" in capsys.readouterr().out
    assert cv2.imread(str(out)).shape == (12, 32, 3)  # two views side by side


def test_batch_footer_names_each_protocol_once():
    hovsg = "hovsg (k=5 nearest predicted points vote for each GT point; counted on GT points)"
    assert protocol_line("hovsg", hovsg) == f"protocol {hovsg}"
    assert protocol_line("hovsg", "hovsg") == "protocol hovsg"
    assert protocol_line("custom", "something else") == "protocol custom: something else"


def test_track_without_data_names_the_option(tmp_path, capsys):
    # before: "no dataset path given (argument path or data.path)", an argument `track` does not have
    assert main(["track", "--out", str(tmp_path / "t")]) == 2
    err = capsys.readouterr().err
    assert "pass --data DIR" in err and "argument path" not in err


def test_run_and_live_name_their_own_options_for_a_scene_folder_in_the_way(tmp_path, capsys):
    # a run directory's scene/ (or live's scene folder) holding something else, e.g. an earlier run's scene
    # made with other `synthetic` settings; before: "pass overwrite=True (--force)", which neither command has
    from ogscene3d.commands.live import main as live_main

    (tmp_path / "run" / "scene").mkdir(parents=True)
    (tmp_path / "run" / "scene" / "old.txt").write_text("x")
    assert main(["run", "--out", str(tmp_path / "run"), "--no-progress", "--device", "cpu"]) == 2
    err = capsys.readouterr().err
    assert "give a new --out, or remove that folder" in err and "--force" not in err
    scene = str(tmp_path / "run" / "scene")
    assert live_main(["--synthetic", "--synthetic-dir", scene, "--device", "cpu"]) == 2
    err = capsys.readouterr().err
    assert "give another --synthetic-dir, or remove that folder" in err and "--force" not in err
