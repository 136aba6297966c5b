"""Which pixel-centre convention a sequence's intrinsics fit: depth reprojected between its frames.

    python benchmarks/pixel_centers.py DATA [--pairs 0:1,0:3,5:9] [--shifts -1,-0.5,0,0.5,1]
                                            [--max-error 0.05] [--json]

Each pair's first frame is back-projected with its depth through the dataset's K (as ogscene3d reads it,
pixel centres at +0.5), moved by the two poses into the second frame and compared there with that frame's
depth, bilinearly sampled where all four neighbours are valid. Points whose depths differ by more than
``--max-error`` metres (occlusions) are left out. This is repeated with cx, then cy, shifted by each of
``--shifts`` pixels. The K as read fits best when shift 0 has the smallest median: on rendered data
(Replica) it tells whether the files count pixel centres from 0 or from 0.5. On a real sensor the pose
and calibration errors are larger than half a pixel and the minimum says little. Nothing is asserted:
this script only reports.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _common import run_main  # noqa: E402

from ogscene3d.camera import Camera  # noqa: E402
from ogscene3d.datasets import open_dataset  # noqa: E402
from ogscene3d.frame import Frame  # noqa: E402


def depth_errors(fi: Frame, fj: Frame, K: np.ndarray, max_error: float) -> np.ndarray:
    """|depth of frame i's points in frame j - frame j's depth there| (metres), over the points j sees."""
    h, w = fi.depth.shape
    pts = Camera.from_K(K, w, h).backproject(fi.depth)[fi.depth > 0].astype(np.float64)
    to_j = np.linalg.inv(fj.pose.astype(np.float64)) @ fi.pose.astype(np.float64)
    q = pts @ to_j[:3, :3].T + to_j[:3, 3]
    z = q[:, 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        # image coordinates with pixel centres at integers, for the bilinear lookup
        x = K[0, 0] * q[:, 0] / z + K[0, 2] - 0.5
        y = K[1, 1] * q[:, 1] / z + K[1, 2] - 0.5
    inside = (z > 0) & (x >= 0) & (x < w - 1) & (y >= 0) & (y < h - 1)
    x, y, z = x[inside], y[inside], z[inside]
    x0, y0 = np.floor(x).astype(np.int64), np.floor(y).astype(np.int64)
    ax, ay = x - x0, y - y0
    D = fj.depth.astype(np.float64)
    c = [D[y0, x0], D[y0, x0 + 1], D[y0 + 1, x0], D[y0 + 1, x0 + 1]]
    dj = c[0] * (1 - ax) * (1 - ay) + c[1] * ax * (1 - ay) + c[2] * (1 - ax) * ay + c[3] * ax * ay
    err = np.abs(dj - z)
    return err[(np.minimum.reduce(c) > 0) & (err < max_error)]


def parse_pairs(text: str) -> list[tuple[int, int]]:
    try:
        pairs = [tuple(int(x) for x in p.split(":")) for p in text.split(",") if p.strip()]
    except ValueError:
        pairs = []
    if not pairs or any(len(p) != 2 for p in pairs):
        raise argparse.ArgumentTypeError(f"expected pairs like 0:1,5:9, got {text!r}")
    return pairs  # type: ignore[return-value]


def parse_shifts(text: str) -> list[float]:
    try:
        shifts = [float(x) for x in text.split(",") if x.strip()]
    except ValueError:
        shifts = []
    if not shifts:
        raise argparse.ArgumentTypeError(f"expected shifts like -0.5,0,0.5, got {text!r}")
    return sorted(set(shifts) | {0.0})


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("data", help="a dataset folder ogscene3d opens (frames need poses and depth)")
    ap.add_argument("--pairs", type=parse_pairs, default=parse_pairs("0:1,0:3,5:9,10:19,2:12"))
    ap.add_argument("--shifts", type=parse_shifts, default=parse_shifts("-1,-0.5,0,0.5,1"))
    ap.add_argument("--max-error", type=float, default=0.05, help="metres; larger differences are occlusions")
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args()

    ds = open_dataset(args.data)
    frames = {i: ds[i] for pair in args.pairs for i in pair if i < len(ds)}
    pairs = [p for p in args.pairs if p[0] in frames and p[1] in frames]
    if not pairs:
        raise SystemExit(f"{args.data}: none of the pairs {args.pairs} is within its {len(ds)} frames")
    if any(frames[i].pose is None for pair in pairs for i in pair):
        raise SystemExit(f"{args.data}: its frames carry no poses; this needs a sequence with poses")

    def median_mm(dcx: float, dcy: float) -> tuple[float, int]:
        K = ds.K.astype(np.float64).copy()
        K[0, 2] += dcx
        K[1, 2] += dcy
        err = np.concatenate([depth_errors(frames[i], frames[j], K, args.max_error) for i, j in pairs])
        return float(np.median(err) * 1000.0), int(err.size)

    rows = []
    for axis in ("cx", "cy"):
        for s in args.shifts:
            med, n = median_mm(s if axis == "cx" else 0.0, s if axis == "cy" else 0.0)
            rows.append({"axis": axis, "shift_px": s, "median_mm": med, "points": n})
    result = {
        "data": str(args.data),
        "kind": ds.kind,
        "pixel_centers": ds.pixel_centers,
        "K": ds.K.tolist(),
        "pairs": pairs,
        "rows": rows,
    }
    if args.json:
        print(json.dumps(result, indent=2))
        return
    print(f"{args.data} ({ds.kind}, read as pixel_centers={ds.pixel_centers}), pairs {pairs}")
    for axis in ("cx", "cy"):
        best = min((r for r in rows if r["axis"] == axis), key=lambda r: r["median_mm"])
        for r in (r for r in rows if r["axis"] == axis):
            mark = "  <- smallest" if r is best else ""
            shift, med, n = r["shift_px"], r["median_mm"], r["points"]
            print(f"  {axis} {shift:+5.2f} px: median {med:.4f} mm ({n} points){mark}")


if __name__ == "__main__":
    run_main(main)
