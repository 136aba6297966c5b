"""Watch the mapper build the synthetic scene in a browser, with the Python API behind ``ogscene3d-live``.

    python examples/live_synthetic.py [--frames 30] [--device cpu] [--port 8080]

The mapping loop below is an ordinary one; the viewer only asks it for a snapshot between frames
(``viewer.wants_snapshot()``: rate-limited, and only while a browser is open), so mapping speed does
not depend on the viewer. ``ogscene3d-live --synthetic`` does the same with pause and save buttons.
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from ogscene3d.config import load_config
from ogscene3d.datasets import configured_scene, open_dataset
from ogscene3d.mapping.mapper import Mapper
from ogscene3d.up_axis import choose_up_axis
from ogscene3d.viewer.app import LiveViewer
from ogscene3d.viewer.snapshot import snapshot_from_mapper


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--frames", type=int, default=30)
    ap.add_argument("--device", default=None)
    ap.add_argument("--port", type=int, default=8080)
    ap.add_argument("--scene", default=None, help="scene folder (default outputs/example-live-synthetic-Nf)")
    ap.add_argument("--force", action="store_true", help="regenerate a --scene made with other arguments")
    args = ap.parse_args()

    cfg = load_config(None, [f"synthetic.frames={args.frames}"])
    s = cfg.synthetic
    # one folder per frame count: configured_scene refuses a folder holding a scene made with others
    scene_dir = args.scene or f"outputs/example-live-synthetic-{s.frames}f"
    scene = configured_scene(
        scene_dir, s, overwrite=args.force, progress=True, remedy="choose another --scene, or pass --force"
    )
    ds = open_dataset(scene, config=cfg.data)
    choose_up_axis(cfg.graph, ds)  # graph.up_axis auto: the scene's own up (what `ogscene3d run` does)
    mapper = Mapper(cfg, args.device)
    viewer = LiveViewer(port=args.port, up=tuple(cfg.graph.up_axis))
    print(f"open {viewer.url} in a browser")

    poses = []
    for frame in ds:
        mapper.process(frame)
        poses.append(frame.pose)
        if viewer.wants_snapshot():
            viewer.publish(
                snapshot_from_mapper(
                    mapper,
                    1_000_000,
                    trajectory=np.stack(poses),
                    frame=frame,
                    map_rev=mapper.keyframe_count,
                    status="mapping",
                )
            )
    mapper.finalize()
    viewer.publish(
        snapshot_from_mapper(
            mapper, 1_000_000, trajectory=np.stack(poses), frame=frame, map_rev=-1, status="finished"
        )
    )
    print("mapping finished; Ctrl-C to stop the viewer")
    try:
        while True:
            time.sleep(1)
    except KeyboardInterrupt:
        viewer.close()


if __name__ == "__main__":
    main()
