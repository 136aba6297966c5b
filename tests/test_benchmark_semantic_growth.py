"""benchmarks/semantic_growth.py: the semantic stages' cost per keyframe late in a scan against early."""

from __future__ import annotations

import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))
semantic_growth = pytest.importorskip("semantic_growth")


def timings(seen: bool) -> dict:
    """Eight keyframes, frames 0-70 every 10: the stages cost 10 ms a keyframe in the first four and 30 in
    the last four, whose views see three times as many Gaussians."""
    frames = list(range(0, 80, 10))
    cost = [10.0] * 4 + [30.0] * 4
    doc = {
        "per_keyframe_frame": frames,
        "per_keyframe_cpu_ms": {"local": cost, "evidence": cost},
        "per_keyframe_ms": {"local": cost, "evidence": cost},
    }
    if seen:  # the long-term pass every second keyframe: one memory view early, four late
        doc["per_keyframe_counts"] = {"visible_gaussians": [1000] * 4 + [3000] * 4,
                                      "memory_views": [0, 1, 0, 1, 0, 4, 0, 4]}  # fmt: skip
    return doc


def test_growth_is_the_late_window_over_the_early_one_also_per_visible_gaussian():
    g = semantic_growth.growth(timings(seen=True), early=30, late=70, window=4)["cpu"]
    assert g["early"]["semantic"] == 20.0 and g["late"]["semantic"] == 60.0
    assert g["ratio"]["semantic"] == pytest.approx(3.0)
    assert g["early"]["visible"] == 1000 and g["late"]["visible"] == 3000
    assert g["ratio"]["per_1k_visible"] == pytest.approx(1.0)  # the cost follows what the views see
    assert g["early"]["memory_views"] == 2 and g["late"]["memory_views"] == 8
    assert semantic_growth._row("run", {"cpu": g, "wall": g})[-1] == "2 -> 8"


def test_growth_without_noted_visible_gaussians_reports_the_times_alone():
    g = semantic_growth.growth(timings(seen=False), early=30, late=70, window=4)["cpu"]
    assert g["ratio"]["semantic"] == pytest.approx(3.0)
    assert "visible" not in g["early"] and "per_1k_visible" not in g["ratio"]
    assert "memory_views" not in g["late"]
    assert semantic_growth._row("run", {"cpu": g, "wall": g})[-3:] == ["-", "-", "-"]


def run_dir(root: Path, name: str, scene: str | None, late_ms: float) -> Path:
    """A run directory of a scene (``scene``: the ``data.path`` its config.yaml names; None: no config)
    whose last four keyframes cost ``late_ms`` each against 10 early."""
    import json

    run = root / name
    run.mkdir(parents=True)
    doc = timings(seen=True)  # the views see 1000 Gaussians early, 3000 late
    cost = [10.0] * 4 + [late_ms] * 4
    doc["per_keyframe_cpu_ms"] = doc["per_keyframe_ms"] = {"local": cost, "evidence": cost}
    (run / "timings.json").write_text(json.dumps(doc))
    if scene is not None:
        (run / "config.yaml").write_text(f"data:\n  kind: synthetic\n  path: {scene}\n")
    return run


def test_rounds_of_one_scene_report_the_median_of_their_ratios(tmp_path, capsys):
    runs = [
        run_dir(tmp_path, "a/scan_2/full", str(tmp_path / "a/scenes/scan_2"), 30.0),  # 3x
        run_dir(tmp_path, "b/scan_2/full", str(tmp_path / "b/scenes/scan_2"), 15.0),  # 1.5x
        run_dir(tmp_path, "c/scan_2/full", str(tmp_path / "c/scenes/scan_2"), 18.0),  # 1.8x
        run_dir(tmp_path, "a/scan_3/full", str(tmp_path / "a/scenes/scan_3"), 11.0),
    ]
    assert semantic_growth.scene_of(runs[0]) == "scan_2"
    out = tmp_path / "out"
    argv = [*map(str, runs), "--early", "30", "--late", "70", "--window", "4", "--out", str(out)]
    assert semantic_growth.main(argv) == 0
    text = capsys.readouterr().out
    assert "max 3.00x over 4 run(s)" in text  # every run
    assert "scan_2: 1.80x (median of 3 run(s): 1.50, 1.80, 3.00)" in text
    assert "mean 1.45x, max 1.80x, 2/2 scene(s) within 2.0x" in text  # one figure a scene
    import json

    scenes = json.loads((out / "semantic_growth.json").read_text())["scenes"]
    assert scenes["scan_2"]["median"] == pytest.approx(1.8)
    assert scenes["scan_2"]["early"]["semantic"] == 20.0 and scenes["scan_2"]["late"]["semantic"] == 36.0
    assert scenes["scan_3"]["runs"] == {str(runs[3]): pytest.approx(1.1)}
    assert scenes["scan_2"]["per_1k_visible"] == pytest.approx(1.8 / 3)  # three times the Gaussians seen


def test_a_run_with_no_config_is_a_scene_of_its_own(tmp_path, capsys):
    runs = [run_dir(tmp_path, "x", None, 30.0), run_dir(tmp_path, "y", None, 30.0)]
    assert semantic_growth.scene_of(runs[0]) == str(runs[0])
    argv = [*map(str, runs), "--early", "30", "--late", "70", "--window", "4", "--out", str(tmp_path / "o")]
    assert semantic_growth.main(argv) == 0
    assert "median of each scene's runs" not in capsys.readouterr().out  # no rounds: the runs' line alone
