r"""Are the default mapping settings sound on small images? Defaults vs configs/synthetic.yaml side by side.

One synthetic room (default 20 frames at 160x120) is generated once and mapped through the CLI
(``ogscene3d run --data SCENE``) with each config; per config the script prints wall time, the share of
``optimize`` in the run's timings.json, the Gaussian count, how far the Gaussians' centres lie from the
true surface (``gt/mesh.ply``: median, 90th percentile, share over 2 cm; Gaussians under 0.1 opacity left
out, as floaters) and the 3D mIoU (HOV-SG protocol, ``ogscene3d.eval.evaluate_run``). It only reports.

    python benchmarks/defaults.py                                  # defaults vs configs/synthetic.yaml
    python benchmarks/defaults.py --frames 20 --width 160 --height 120 --json out.json
    python benchmarks/defaults.py --config NAME=path.yaml --config NAME2=-   # '-' = the defaults
    python benchmarks/defaults.py --config iters3=-,mapping.optimize.iters=3      # a config plus overrides
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _common import print_table, run_main  # noqa: E402

REPO = Path(__file__).resolve().parents[1]
MIN_OPACITY = 0.1


def surface_distance(means: np.ndarray, mesh_path: Path) -> np.ndarray:
    """Unsigned distance (metres) of each point to the triangle mesh at ``mesh_path`` (Open3D ray-casting
    scene, exact point-to-triangle distance)."""
    import open3d as o3d

    mesh = o3d.io.read_triangle_mesh(str(mesh_path))
    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(o3d.t.geometry.TriangleMesh.from_legacy(mesh))
    q = o3d.core.Tensor(np.ascontiguousarray(means, dtype=np.float32))
    return scene.compute_distance(q).numpy()


def measure(scene: Path, out: Path, config: str | None, device: str, overrides: list[str]) -> dict:
    cmd = [sys.executable, "-m", "ogscene3d.cli", "run", "--data", str(scene), "--out", str(out)]
    cmd += ["--device", device, "--no-progress"]
    if config:
        cmd += ["--config", config]
    for o in overrides:
        cmd += ["--set", o]
    t0 = time.perf_counter()
    proc = subprocess.run(cmd, capture_output=True, text=True)
    wall = time.perf_counter() - t0
    if proc.returncode != 0:
        raise SystemExit(f"{' '.join(cmd)} failed ({proc.returncode}):\n{proc.stderr[-3000:]}")
    from ogscene3d.eval import evaluate_run
    from ogscene3d.gaussians import GaussianMap

    gm = GaussianMap.load_npz(out / "map.npz")
    means = gm.means.detach().numpy()
    keep = gm.opacities.detach().numpy() >= MIN_OPACITY
    d = surface_distance(means[keep], scene / "gt" / "mesh.ply")
    res = evaluate_run(out, scene)
    timings = json.loads((out / "timings.json").read_text())
    secs = timings.get("seconds", timings)
    opt = float(secs.get("optimize", float("nan"))) if isinstance(secs, dict) else float("nan")
    total = sum(v for v in secs.values() if isinstance(v, int | float)) if isinstance(secs, dict) else 0.0
    return {
        "wall_s": wall,
        "optimize_share": opt / total if total > 0 else float("nan"),
        "gaussians": int(len(means)),
        "dist_median_cm": 100 * float(np.median(d)),
        "dist_p90_cm": 100 * float(np.percentile(d, 90)),
        "over_2cm_pct": 100 * float(np.mean(d > 0.02)),
        "miou_pct": 100 * float(res.semantic["hovsg"].miou),
    }


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--frames", type=int, default=20)
    ap.add_argument("--width", type=int, default=160)
    ap.add_argument("--height", type=int, default=120)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--device", default="cpu")
    ap.add_argument(
        "--config",
        action="append",
        metavar="NAME=PATH",
        help="a config to compare ('-' for the defaults), then ,KEY=VALUE overrides; default: the defaults "
        "and configs/synthetic.yaml",
    )
    ap.add_argument("--set", action="append", default=[], metavar="KEY=VALUE", help="override for every run")
    ap.add_argument("--json", help="write the rows here")
    args = ap.parse_args()
    configs = args.config or ["defaults=-", f"synthetic.yaml={REPO / 'configs' / 'synthetic.yaml'}"]
    from ogscene3d.datasets.synthetic import make_synthetic_scene

    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        scene = make_synthetic_scene(
            Path(tmp) / "scene", args.seed, args.frames, args.width, args.height, device="cpu"
        )
        for spec in configs:
            name, _, rest = spec.partition("=")
            path, *extra = rest.split(",")
            run_dir = Path(tmp) / f"run_{len(rows)}"
            row = measure(scene, run_dir, None if path in ("", "-") else path, args.device, args.set + extra)
            rows.append({"config": name, **row})
            print(f"{name}: {row}", file=sys.stderr, flush=True)
    cols = [
        ("config", "config", ""),
        ("wall_s", "wall s", ".0f"),
        ("optimize_share", "optimize share", ".0%"),
        ("gaussians", "Gaussians", "d"),
        ("dist_median_cm", "median dist cm", ".2f"),
        ("dist_p90_cm", "p90 dist cm", ".2f"),
        ("over_2cm_pct", "> 2 cm %", ".1f"),
        ("miou_pct", "mIoU %", ".2f"),
    ]
    print(f"synthetic seed {args.seed}, {args.frames} frames at {args.width}x{args.height}, "
          f"{os.cpu_count()} CPUs, device {args.device}")
    print_table(
        [{h: (format(r[k], f) if f else r[k]) for k, h, f in cols} for r in rows], [h for _, h, _ in cols]
    )
    if args.json:
        Path(args.json).write_text(json.dumps(rows, indent=2))
    return 0


if __name__ == "__main__":
    run_main(main)
