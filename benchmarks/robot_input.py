"""Reading recordings against reading the same frames from a folder: the time to open each (the ROS reader
scans every message header once) and to read every frame, side by side, as ratios to the folder.

    python benchmarks/robot_input.py [--frames 30] [--size 320x240] [--work DIR]

The recordings are written from a synthetic scene with the test suite's writers
(tests/helpers/robot_recordings.py: rosbags' ROS 1 and ROS 2 writers, a Record3D .r3d zip); needs
``ogscene3d[ros,record3d]``.
"""

from __future__ import annotations

import argparse
import shutil
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
from _common import positive_int, run_main

# the recordings' writers are test helpers (they need no ROS install either)
sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "tests" / "helpers"))


def _time(fn, repeats: int = 3) -> float:
    best = float("inf")
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - t0)
    return best


def main() -> int:
    from robot_recordings import BagSpec, write_bag, write_r3d

    from ogscene3d.cli_types import image_size
    from ogscene3d.datasets import make_synthetic_scene, open_dataset

    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--frames", type=positive_int, default=30)
    p.add_argument("--size", type=image_size(16, "320x240"), default=(320, 240), metavar="WxH")
    p.add_argument("--work", default=None, help="folder for the scene and recordings (default: a temporary)")
    args = p.parse_args()
    work = Path(args.work) if args.work else Path(tempfile.mkdtemp(prefix="robot_input_"))
    try:
        w, h = args.size
        scene = make_synthetic_scene(work / "scene", 0, args.frames, w, h)
        ds = open_dataset(scene)
        frames = list(ds)
        K = ds.K.astype(np.float64).copy()
        K[:2, 2] -= 0.5
        # the folder as the Replica layout reads it: colour, depth and pose (the synthetic layout would read
        # segments and ground truth too, which recordings do not carry)
        sources = {"folder (replica layout)": scene}
        for storage, name in (("ros1", "rec.bag"), ("sqlite3", "rec_sqlite3"), ("mcap", "rec_mcap")):
            sources[f"ROS bag {storage}"] = write_bag(work / name, frames, K, BagSpec(storage=storage))
        sources["ROS bag ros1, jpeg + compressedDepth"] = write_bag(
            work / "rec_c.bag", frames, K, BagSpec(colour="jpeg", depth="compressedDepth")
        )
        sources["Record3D .r3d"] = write_r3d(work / "rec.r3d", frames, K)
        print(f"{args.frames} frames of {w}x{h}; best of 3 runs; ratio = time / the folder's")
        head = ("source", "open s", "ratio", "read all s", "ratio", "ms/frame")
        print("{:40s} {:>8s} {:>6s} {:>11s} {:>6s} {:>9s}".format(*head))
        base = None
        for label, path in sources.items():
            kind = "replica" if path == scene else "auto"
            t_open = _time(lambda path=path, kind=kind: open_dataset(path, kind=kind))
            opened = open_dataset(path, kind=kind)
            t_read = _time(lambda opened=opened: [f for f in opened])
            if base is None:
                base = (t_open, t_read)
            print(
                f"{label:40s} {t_open:8.3f} {t_open / base[0]:6.1f} {t_read:11.3f} {t_read / base[1]:6.2f} "
                f"{1e3 * t_read / len(opened):9.2f}"
            )
    finally:
        if not args.work:
            shutil.rmtree(work, ignore_errors=True)
    return 0


if __name__ == "__main__":
    run_main(main)
