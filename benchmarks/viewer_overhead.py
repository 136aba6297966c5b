"""What the live viewer costs: the mapping thread's snapshot copy, and the push thread's scene update.

    python benchmarks/viewer_overhead.py [--sizes 100k,1m] [--device cpu] [--repeats 3]

Per map size N it reports (median of --repeats, milliseconds):
- snapshot: ``snapshot_from_mapper`` (on the mapping thread, between two frames) with the default
  budget (1M Gaussians copied at most) and with a 200k budget;
- splats / points: the push thread turning a snapshot into viser messages (covariances, colours,
  decimation to the default budgets: 200k splats, 1M points), with no browser attached.
``publish`` itself only swaps a reference. At the default 4 Hz the snapshot cost is paid at most four
times per second, and never while no browser is open.
"""

from __future__ import annotations

import argparse
import statistics
import time

import torch
from _common import parse_count, positive_int, run_main, synthetic_gaussians

from ogscene3d.device import resolve_device
from ogscene3d.gaussians import GaussianMap
from ogscene3d.viewer.scene import SceneLayers, ViewerSettings
from ogscene3d.viewer.snapshot import snapshot_from_mapper


class _MapperView:
    """The attributes ``snapshot_from_mapper`` reads."""

    def __init__(self, gm: GaussianMap) -> None:
        self.map = gm
        self.frames_seen = self.keyframe_count = 0
        self._graph = None

        class _T:
            def as_dict(self) -> dict:
                return {}

        self.timings = _T()


def _median_ms(fn, repeats: int, device: torch.device) -> float:
    out = []
    for _ in range(repeats):
        if device.type == "cuda":
            torch.cuda.synchronize(device)
        t0 = time.perf_counter()
        fn()
        out.append(1000 * (time.perf_counter() - t0))
    return statistics.median(out)


def measure(n: int, server, device: torch.device, repeats: int) -> tuple[float, float, float, float]:
    """(snapshot 1M budget, snapshot 200k budget, splats push, points push) in ms for N Gaussians."""
    means, quats, scales, opac, colors, labels, conf = synthetic_gaussians(n, device)
    gm = GaussianMap(device, capacity=n)
    gm.append(
        means,
        colors,
        scales.log(),
        labels=labels,
        confidences=conf,
        quats=quats,
        opacity_logits=torch.logit(opac),
    )
    mv = _MapperView(gm)
    t_full = _median_ms(lambda: snapshot_from_mapper(mv, 1_000_000), repeats, device)
    t_small = _median_ms(lambda: snapshot_from_mapper(mv, 200_000), repeats, device)
    snap = snapshot_from_mapper(mv, 1_000_000)
    layers = SceneLayers(server)
    layers.update_bounds(snap)
    splats, points = ViewerSettings(render="splats"), ViewerSettings(render="points")
    t_splats = _median_ms(lambda: layers.update_map(snap, splats, None), repeats, device)
    t_points = _median_ms(lambda: layers.update_map(snap, points, None), repeats, device)
    return t_full, t_small, t_splats, t_points


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--sizes", default="100k,1m")
    ap.add_argument("--device", default="cpu")
    ap.add_argument("--repeats", type=positive_int, default=3)
    args = ap.parse_args()
    device = resolve_device(args.device)  # before viser starts a server: a missing GPU is one line
    import viser

    server = viser.ViserServer(host="127.0.0.1", port=0, verbose=False)
    print(f"{'N':>9} {'snapshot 1M':>12} {'snapshot 200k':>14} {'splats push':>12} {'points push':>12}  (ms)")
    try:
        for n in (parse_count(s) for s in args.sizes.split(",")):
            t = measure(n, server, device, args.repeats)
            print(f"{n:>9} {t[0]:>12.1f} {t[1]:>14.1f} {t[2]:>12.1f} {t[3]:>12.1f}")
    finally:
        server.stop()


if __name__ == "__main__":
    run_main(main)
