"""The mapper's per-module times and per-keyframe quantities (mapping/timings.py)."""

from __future__ import annotations

import torch

from ogscene3d.mapping.timings import Timings


def test_a_noted_quantity_is_written_per_keyframe_beside_the_times():
    """``note`` keeps a quantity in the current keyframe's row (0 in a keyframe that did not note it); a
    note outside a keyframe (the end of stream's passes) is not kept; a checkpoint's rows come back with it,
    and rows written before notes were kept load with none."""
    t = Timings(torch.device("cpu"))
    for frame, seen in ((0, 120), (5, None), (9, 480)):
        t.begin_keyframe(frame)
        with t.section("evidence"):
            pass
        if seen is not None:
            t.note("visible_gaussians", seen)
        t.end_keyframe()
    t.note("visible_gaussians", 7)
    doc = t.as_dict()
    assert doc["per_keyframe_frame"] == [0, 5, 9]
    assert doc["per_keyframe_counts"] == {"visible_gaussians": [120, 0, 480]}
    assert len(doc["per_keyframe_cpu_ms"]["evidence"]) == 3
    back = Timings(torch.device("cpu"))
    back.load_state(t.state())
    assert back.as_dict()["per_keyframe_counts"] == doc["per_keyframe_counts"]
    old = t.state()
    old["per_keyframe"] = [{k: v for k, v in row.items() if k != "counts"} for row in old["per_keyframe"]]
    back.load_state(old)
    assert back.as_dict()["per_keyframe_counts"] == {}
