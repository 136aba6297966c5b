"""How fast a broken dataset folder fails, and what the checks made when a dataset opens cost.

    python benchmarks/open_checks.py [--frames 300] [--size 1200x680] [--runs 3] [--dir DIR]

Writes a Replica-layout folder of ``--frames`` frames at ``--size`` (JPEG colour, 16-bit PNG depth, traj.txt,
cam_params.json; about the sizes of NICE-SLAM's Replica files), then times ``open_dataset`` (median of
``--runs``, warm file cache) on the sound folder and with frame 5's colour image cut to half its bytes, or
emptied; and, for scale, reading (decoding) one frame. Issue 42's target: a truncated or empty image in a
300-frame folder fails in under 5 s (before the checks it was found only when mapping reached the frame).
Nothing is asserted: this script only reports.
"""

from __future__ import annotations

import argparse
import shutil
import statistics
import sys
import tempfile
import time
from pathlib import Path

import cv2
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _common import positive_int, run_main  # noqa: E402

from ogscene3d.cli_types import image_size  # noqa: E402
from ogscene3d.datasets import open_dataset  # noqa: E402
from ogscene3d.errors import DataError  # noqa: E402


def write_folder(root: Path, frames: int, w: int, h: int) -> Path:
    """A Replica-layout folder: textured colour and smooth depth, so that the files have realistic sizes."""
    rng = np.random.default_rng(0)
    res = root / "results"
    res.mkdir(parents=True)
    yy, xx = np.mgrid[0:h, 0:w]
    for i in range(frames):
        noise = rng.integers(0, 40, (h, w, 3), dtype=np.uint8)
        rgb = ((xx + 3 * i) % 256).astype(np.uint8)[..., None] + noise
        cv2.imwrite(str(res / f"frame{i:06d}.jpg"), rgb, [cv2.IMWRITE_JPEG_QUALITY, 95])
        depth = (6553.5 * (1.0 + 2.0 * yy / h + 0.001 * i)).astype(np.uint16)
        cv2.imwrite(str(res / f"depth{i:06d}.png"), depth)
    pose = " ".join(map(str, np.eye(4).ravel())) + "\n"
    (root / "traj.txt").write_text(pose * frames)
    cam = f'{{"camera": {{"w": {w}, "h": {h}, "fx": 600.0, "fy": 600.0, "cx": {w / 2}, "cy": {h / 2}, '
    (root / "cam_params.json").write_text(cam + '"scale": 6553.5}}')
    return root


def timed(fn, runs: int) -> tuple[float, str]:
    """(median seconds, outcome) of ``fn()`` over ``runs`` calls; outcome: "ok" or the DataError's text."""
    times, outcome = [], ""
    for _ in range(runs):
        t0 = time.perf_counter()
        try:
            fn()
            outcome = "ok"
        except DataError as e:
            outcome = str(e)
        times.append(time.perf_counter() - t0)
    return statistics.median(times), outcome


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=positive_int, default=300)
    ap.add_argument("--size", type=image_size(8, "1200x680"), default=(1200, 680), metavar="WxH")
    ap.add_argument("--runs", type=positive_int, default=3)
    ap.add_argument("--dir", default=None, help="where to write the folder (default: a temporary one)")
    args = ap.parse_args()
    w, h = args.size
    base = Path(args.dir) if args.dir else Path(tempfile.mkdtemp(prefix="open-checks-"))
    root = base / "room"
    if root.exists():
        shutil.rmtree(root)
    t0 = time.perf_counter()
    write_folder(root, args.frames, w, h)
    size_mb = sum(p.stat().st_size for p in root.rglob("*") if p.is_file()) / 1e6
    print(f"{args.frames} frames at {w}x{h}: {size_mb:.0f} MB written in {time.perf_counter() - t0:.1f} s")
    jpg = root / "results" / "frame000005.jpg"
    good = jpg.read_bytes()
    rows = [("sound folder: open_dataset", *timed(lambda: open_dataset(root), args.runs))]
    ds = open_dataset(root)
    rows.append(("sound folder: read one frame (decode)", *timed(lambda: ds[0], args.runs)))
    jpg.write_bytes(good[: len(good) // 2])
    rows.append(("frame 5 truncated: open_dataset", *timed(lambda: open_dataset(root), args.runs)))
    jpg.write_bytes(b"")
    rows.append(("frame 5 empty: open_dataset", *timed(lambda: open_dataset(root), args.runs)))
    jpg.write_bytes(good)
    for what, seconds, outcome in rows:
        tail = outcome if outcome in ("ok", "") else "DataError: " + outcome.split("; ", 1)[-1][:120]
        print(f"{what:<40} {seconds:8.3f} s   {tail}")
    if not args.dir:
        shutil.rmtree(base)
    return 0


if __name__ == "__main__":
    run_main(main)
