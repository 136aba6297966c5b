"""Simulated SAM segments for a whole synthetic scene (e.g. at another noise level than the one it was
made with), in the precomputed-segments format. Here, not in :mod:`ogscene3d.segmentation.simulated`: it
reads a dataset, and datasets build on segmentation, not the other way round."""

from __future__ import annotations

from pathlib import Path

from ..segmentation.precomputed import write_segments
from ..segmentation.simulated import SimulatedSegmenter
from .loader import open_dataset
from .long_scan import merges_by_frame
from .synthetic import load_first_views


def simulate_scene_segments(
    scene_dir: str | Path, out_dir: str | Path, noise: str = "default", seed: int = 0
) -> Path:
    """Write simulated segments for every frame of a synthetic scene (e.g. another noise level)."""
    ds = open_dataset(scene_dir, kind="synthetic")
    # what each object stands or hangs on: SAM-like noise merges an object with its support in some views
    support = {k: v["support"] for k, v in ds.gt["instances"].items() if v.get("support") is not None}
    # a long scan's objects merged with the floor or a neighbour in their first views (the scene's plan)
    seg = SimulatedSegmenter(noise, seed, support, merges_by_frame(load_first_views(scene_dir)))
    out = Path(out_dir)
    for frame in ds:
        s = seg(frame.rgb, frame.depth, gt_instances=frame.gt_instances, frame_index=frame.index)
        write_segments(out, frame.name, s.ids, s.scores)
    return out
