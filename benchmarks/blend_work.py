"""Blending work per pixel, counted (not timed): how many Gaussians a 32-lane warp evaluates per pixel.

    python benchmarks/blend_work.py                      # 500k Gaussians, 1200x680, both scenes
    python benchmarks/blend_work.py --counts 20k --width 160 --height 120

Emulates the CUDA blending loop in torch on the real tile lists (ours, from ``bin_gaussians``): a warp
walks its tile's depth-sorted list until all its pixels have ended (T <= 1e-4), and evaluates either
every entry (no culling) or only those whose alpha >= 1/255 box and ellipse reach its pixels (8x4
blocks, as the kernels do). Colour (alpha) and semantic (confidence x alpha; labelled Gaussians of
confidence > 0 only) rays are counted separately; for semantic rays also the entries at which a warp
runs the label-buffer code, when every vote updates the buffer and when a run of one label's consecutive
votes updates it once (as kernels/semantic.py does; the contribution walk's R_p look-ups follow the same
runs). Machine-independent, so a CPU run predicts how the blending kernels' work changes on a GPU.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import torch

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _common import SEMANTIC_SCENES, camera, parse_count, positive_int, print_table, run_main  # noqa: E402

from ogscene3d.rendering._projection import Project, bin_gaussians  # noqa: E402

TILE = 16


def _warp_blocks() -> list[tuple[int, int]]:
    """Pixel offsets (x, y) of the eight 8x4 warp blocks of a 16x16 tile."""
    return [((w % 2) * 8, (w // 2) * 4) for w in range(TILE * TILE // 32)]


def _min_sigma_in_box(mean: torch.Tensor, conic: torch.Tensor, box: tuple[float, ...]) -> torch.Tensor:
    """Minimum of sigma over the box (x_lo, x_hi, y_lo, y_hi), as kernels/raster.py ellipse_meets_box."""
    x_lo, x_hi, y_lo, y_hi = box
    a, b, c = conic.unbind(-1)
    mx, my = mean.unbind(-1)
    inside = (mx >= x_lo) & (mx <= x_hi) & (my >= y_lo) & (my <= y_hi)
    best = torch.full_like(a, float("inf"))
    for edge in range(4):
        if edge < 2:
            dx = mx - (x_lo if edge == 0 else x_hi)
            dy = torch.clamp(-b * dx / c, min=my - y_hi, max=my - y_lo)
        else:
            dy = my - (y_lo if edge == 2 else y_hi)
            dx = torch.clamp(-b * dy / a, min=mx - x_hi, max=mx - x_lo)
        best = torch.minimum(best, 0.5 * (a * dx * dx + c * dy * dy) + b * dx * dy)
    return torch.where(inside, torch.zeros_like(best), best)


def count(scene: str, n: int, width: int, height: int, semantic: bool, max_tiles: int) -> dict:
    means, quats, scales, opac, _, labels, conf = SEMANTIC_SCENES[scene](n, torch.device("cpu"))
    vm, K = camera(width, height, torch.device("cpu"))
    with torch.no_grad():
        m2d, conics, depths, radii = Project.apply(
            means, quats, scales, opac, vm, K, width, height, 0.01, 1e10, 0.3
        )
        voters = (labels, conf) if semantic else None
        bins = bin_gaussians(m2d, conics, opac, radii, depths, width, height, TILE, voters=voters)
    m2d, conics, ext = m2d[0], conics[0], bins.extents[0]
    ys, xs = torch.meshgrid(torch.arange(TILE) + 0.5, torch.arange(TILE) + 0.5, indexing="ij")
    n_tiles = bins.tile_start.numel()
    step = max(1, n_tiles // max_tiles)
    totals = {"entries": 0, "no_cull": 0, "cull": 0, "pixels": 0, "updates": 0, "run_updates": 0}
    for tile in range(0, n_tiles, step):
        s, e = int(bins.tile_start[tile]), int(bins.tile_end[tile])
        ids = bins.isect_ids[s:e].long()
        ox, oy = (tile % bins.tiles_x) * TILE, (tile // bins.tiles_x) * TILE
        valid = ((xs + ox) < width) & ((ys + oy) < height)
        totals["pixels"] += int(valid.sum())
        totals["entries"] += len(ids) * int(valid.sum())
        if len(ids) == 0:
            continue
        dx = m2d[ids, 0][None, None] - (xs + ox)[..., None]
        dy = m2d[ids, 1][None, None] - (ys + oy)[..., None]
        c = conics[ids]
        sigma = 0.5 * (c[:, 0] * dx * dx + c[:, 2] * dy * dy) + c[:, 1] * dx * dy
        alpha = torch.clamp(opac[ids] * torch.exp(-sigma), max=0.99)
        alpha = torch.where((sigma >= 0) & (alpha >= 1 / 255), alpha, torch.zeros_like(alpha))
        if semantic:
            alpha = alpha * conf[ids]
        ended = torch.cumprod(1 - alpha, dim=-1) <= 1e-4
        # entries a pixel walks: up to and including the one that ends it, else the whole list
        walk = torch.where(
            ended.any(-1),
            ended.float().argmax(-1) + 1,
            torch.full_like(ended[..., 0], len(ids), dtype=torch.long),
        )
        walk = torch.where(valid, walk, torch.zeros_like(walk))
        if semantic:
            # a vote is a blended entry (before the one that ends the pixel); it starts a run where the
            # pixel's previous vote had another label
            j = torch.arange(len(ids))
            last = walk - ended.any(-1).long()  # entries before the one that ends the pixel
            voted = (alpha > 0) & (j < last[..., None]) & valid[..., None]
            previous = torch.cummax(torch.where(voted, j, -1), dim=-1).values
            previous = torch.cat([torch.full_like(previous[..., :1], -1), previous[..., :-1]], -1)
            lab = labels[ids]
            starts = voted & ((previous < 0) | (lab[previous.clamp(min=0)] != lab))
        for bx, by in _warp_blocks():
            lanes = valid[by : by + 4, bx : bx + 8]
            if not lanes.any():
                continue
            depth = int(walk[by : by + 4, bx : bx + 8].max())
            x0, x1, y0, y1 = ox + bx + 0.5, ox + bx + 7.5, oy + by + 0.5, oy + by + 3.5
            e_ = ext[ids[:depth]]
            mx, my = m2d[ids[:depth], 0], m2d[ids[:depth], 1]
            reach = (e_[:, 0] >= 0) & (mx + e_[:, 0] >= x0) & (mx - e_[:, 0] <= x1)
            reach &= (my + e_[:, 1] >= y0) & (my - e_[:, 1] <= y1)
            limit = torch.log(opac[ids[:depth]] * 255.0) + 0.01
            reach &= (
                _min_sigma_in_box(torch.stack([mx, my], -1), conics[ids[:depth]], (x0, x1, y0, y1)) <= limit
            )
            totals["no_cull"] += depth * int(lanes.sum())
            totals["cull"] += int(reach.sum()) * int(lanes.sum())
            if semantic:
                # the warp runs the buffer code for an entry where any of its lanes needs it
                block = (slice(by, by + 4), slice(bx, bx + 8))
                totals["updates"] += int(voted[block].flatten(0, 1).any(0).sum()) * int(lanes.sum())
                totals["run_updates"] += int(starts[block].flatten(0, 1).any(0).sum()) * int(lanes.sum())
    px = max(totals["pixels"], 1)
    return {
        "scene": scene,
        "N": n,
        "rays": "semantic" if semantic else "colour",
        "isects": bins.num_intersections,
        "list_per_px": totals["entries"] / px,
        "evaluated_no_cull": totals["no_cull"] / px,
        "evaluated_cull": totals["cull"] / px,
        "reduction": totals["no_cull"] / max(totals["cull"], 1),
        # per pixel, entries for which a warp updates the label buffer: at every vote, or once per run
        "buffer_updates_per_vote": totals["updates"] / px if semantic else float("nan"),
        "buffer_updates_per_run": totals["run_updates"] / px if semantic else float("nan"),
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--counts", default="500k")
    ap.add_argument("--width", type=positive_int, default=1200)
    ap.add_argument("--height", type=positive_int, default=680)
    ap.add_argument("--max-tiles", type=positive_int, default=800, help="tiles sampled evenly (all if fewer)")
    ap.add_argument("--scene", choices=sorted(SEMANTIC_SCENES), action="append", help="default: both")
    args = ap.parse_args()
    rows = [
        count(scene, parse_count(c), args.width, args.height, semantic, args.max_tiles)
        for scene in args.scene or sorted(SEMANTIC_SCENES)
        for c in args.counts.split(",")
        for semantic in (False, True)
    ]
    print(f"Gaussians evaluated per pixel by 32-lane warps, {args.width}x{args.height}, {TILE}x{TILE} tiles")
    print_table(rows, list(rows[0].keys()))


if __name__ == "__main__":
    run_main(main)
