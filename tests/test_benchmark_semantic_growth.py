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
