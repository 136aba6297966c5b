"""New Gaussians ("probes") of a keyframe from its depth and segmentation (paper Sec. III-B.2, first part).

Valid-depth pixels on a regular grid of step ``step`` (so about one probe per ``step**2`` pixels) are
back-projected to world points; a segment with fewer than ``dense_below`` grid probes
(``mapping.init.dense_below``: a book, a light switch) gets one at every pixel instead. Every probe of a
segment takes part in the segment's KNN association; only the probes whose pixel the current map does not
already explain (rendered alpha below ``alpha_thresh``, or observed depth in front of the rendered depth by
more than ``depth_margin``) become new Gaussians. A small segment's probe also becomes one where no
Gaussian centre lies within its pixel's footprint: a book that an earlier view merged with its shelf is
covered (explained) by the shelf's Gaussians, a grid cell apart, and two or three of them on a book are too
few for any later decision to tell it from the shelf or the book beside it. Scale: isotropic, the footprint
of one grid cell at that depth (depth * step / focal; one pixel for the dense ones), so neighbouring
Gaussians overlap; rotation identity; colour from the RGB.

The paper initializes new Gaussians from every pixel of every segment of each keyframe (``step`` 1);
adding only the unexplained ones keeps a revisited surface from being duplicated at every keyframe (as in
SplaTAM), and the explained probes still stand for G_m in Eq. 4 (``local.py``; ``fill_unlabeled`` there lets
an existing unlabelled Gaussian under a labelled segment play the new Gaussian's part).
A probe's confidence is its segment's SAM score rescaled from ``score_range`` to ``conf_range`` (paper:
[0.88, 1] -> [0.5, 1], clamped); a segment without a score (a segmenter or a segments folder that gives
none) counts as scored 1, i.e. confidence 1. Pixels outside every segment get confidence 0.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import torch

from ..config import InitConfig
from ..frame import Frame
from ..gaussians import GaussianMap
from ..rendering import rasterization
from .local import rescale_sam_scores
from .neighbors import knn

# metres: a small segment's pixel this far from the segment's median depth is the background seen past the
# object's edge (the floor beside a cup), not the object: it is left to the map's rendering test
DENSE_DEPTH = 0.05


@dataclass
class Probes:
    """A keyframe's candidate Gaussians (P of them) and its segments (S of them), on one device."""

    means: torch.Tensor  # [P,3] world
    colors: torch.Tensor  # [P,3] in [0,1]
    log_scales: torch.Tensor  # [P] isotropic log sigma
    seg: torch.Tensor  # [P] int64 segment index in 0..S-1, -1 = pixel outside every segment
    conf: torch.Tensor  # [P] rescaled SAM score of the probe's segment (0 outside segments)
    new: torch.Tensor  # [P] bool: not explained by the map -> becomes a Gaussian
    pix: torch.Tensor  # [P] int64 flat pixel index (v * W + u)
    seg_ids: torch.Tensor  # [S] int64 the frame's own segment ids
    seg_conf: torch.Tensor  # [S] float32 rescaled SAM scores

    def __len__(self) -> int:
        return int(self.means.shape[0])


def grid_mask(height: int, width: int, step: int) -> np.ndarray:
    """Bool [H,W]: the subsampling grid (pixel centres of step x step cells)."""
    m = np.zeros((height, width), dtype=bool)
    o = step // 2
    m[o::step, o::step] = True
    return m


def make_probes(
    frame: Frame,
    segments: np.ndarray | None,
    scores: dict[int, float],
    device: torch.device,
    cfg: InitConfig,
    *,
    score_range: tuple[float, float] = (0.88, 1.0),
    conf_range: tuple[float, float] = (0.5, 1.0),
    rendered: tuple[torch.Tensor, torch.Tensor] | None = None,
    depth_range: tuple[float, float] = (0.0, 0.0),
    map_means: torch.Tensor | None = None,
) -> Probes:
    """Back-project the grid pixels of ``frame`` (must have a pose), the grid and thresholds from ``cfg``
    (the ``mapping.init`` section). ``segments`` int [H,W] (0 or negative = none) or None; ``rendered``:
    (alpha, expected depth) [H,W] of the map at the frame's pose (None when the map is empty: every probe is
    new); ``depth_range``: ``data.min_depth``, ``data.max_depth`` (0: no limit); ``map_means``: the map's
    Gaussian centres [N,3], which a small segment's probes need within their footprint (None: not tested)."""
    if frame.pose is None:
        raise ValueError(f"frame {frame.index}: no pose; mapping needs camera-to-world poses")
    step, (min_depth, max_depth) = max(1, round(math.sqrt(cfg.pixels_per_gaussian))), depth_range
    o = step // 2
    # only the grid pixels are uploaded (1/step^2 of the image): the back-projection runs on the device,
    # in float64 as numpy did, so the probes match the host computation to the last float32 bit
    grid = (slice(o, None, step), slice(o, None, step))
    up = lambda a: torch.from_numpy(np.ascontiguousarray(a)).to(device)  # noqa: E731
    depth = up(np.asarray(frame.depth, dtype=np.float32)[grid])
    ok = torch.isfinite(depth) & (depth > max(min_depth, 0.0))
    if max_depth > 0:
        ok &= depth <= max_depth
    gv, gu = torch.nonzero(ok, as_tuple=True)
    vv, uu = gv * step + o, gu * step + o
    z32 = depth[gv, gu]
    extra = _dense_pixels(frame, segments, step, cfg.dense_below, min_depth, max_depth) if step > 1 else None
    cell = torch.full((len(z32),), float(step), dtype=torch.float64, device=device)
    if extra is not None:  # small segments: every pixel (their grid probes are already in)
        ev, eu = (up(a) for a in extra)
        vv, uu = torch.cat([vv, ev]), torch.cat([uu, eu])
        z32 = torch.cat([z32, up(np.asarray(frame.depth, dtype=np.float32)[extra])])
        cell = torch.cat([cell, torch.ones(len(ev), dtype=torch.float64, device=device)])
    z = z32.double()
    K = frame.K.astype(np.float64)
    x = (uu.double() + 0.5 - K[0, 2]) / K[0, 0] * z  # int + float is float32 in torch: widen first
    y = (vv.double() + 0.5 - K[1, 2]) / K[1, 1] * z
    pc = torch.stack([x, y, z], 1)
    pose = torch.as_tensor(frame.pose, dtype=torch.float64, device=device)
    pw = pc @ pose[:3, :3].T + pose[:3, 3]
    focal = 0.5 * (K[0, 0] + K[1, 1])
    log_s = torch.log(torch.clamp(z * cell / focal, min=1e-6))
    colors = up(frame.rgb[grid])[gv, gu].float() / 255.0
    if extra is not None:
        colors = torch.cat([colors, up(frame.rgb[extra]).float() / 255.0])
    pix = vv * frame.width + uu
    if segments is not None:
        sid = up(np.asarray(segments)[grid].astype(np.int64))[gv, gu]
        if extra is not None:
            sid = torch.cat([sid, up(np.asarray(segments)[extra].astype(np.int64))])
        seg, seg_ids, raw = _probe_segments(sid, scores)
    else:
        seg_ids = torch.zeros(0, dtype=torch.int64, device=device)
        seg = torch.full((len(z),), -1, dtype=torch.int64, device=device)
        raw = np.zeros(0, dtype=np.float32)
    seg_conf = rescale_sam_scores(torch.as_tensor(raw, device=device), score_range, conf_range)
    conf = torch.where(
        seg >= 0, seg_conf[seg.clamp(min=0)] if len(seg_ids) else 0.0, torch.zeros_like(seg).float()
    )
    new = _unexplained(pix, z32, rendered, cfg.alpha_thresh, cfg.depth_margin)
    if extra is not None and map_means is not None and len(map_means):
        tail = slice(len(z) - len(extra[0]), len(z))  # the small segments' off-grid probes come last
        on_object = (z[tail] - _segment_medians(z, seg, len(seg_ids))[seg[tail]]).abs() <= DENSE_DEPTH
        new[tail] |= on_object & _uncovered(map_means, pw[tail].float(), (z[tail] / focal).float())
    return Probes(
        means=pw.float(),
        colors=colors,
        log_scales=log_s.float(),
        seg=seg,
        conf=conf.float(),
        new=new,
        pix=pix,
        seg_ids=seg_ids,
        seg_conf=seg_conf,
    )


def _unexplained(
    pix: torch.Tensor, z: torch.Tensor, rendered: tuple | None, alpha_thresh: float, depth_margin: float
) -> torch.Tensor:
    """[P] bool: the probes (flat pixel ``pix``, observed depth ``z``) that the rendered map (alpha,
    expected depth) does not explain: alpha below ``alpha_thresh``, or observed depth ``depth_margin`` in
    front of the render (all of them when the map is empty: ``rendered`` None)."""
    if rendered is None:
        return torch.ones(len(z), dtype=torch.bool, device=z.device)
    a = rendered[0].reshape(-1).to(z.device)[pix]
    d = rendered[1].reshape(-1).to(z.device)[pix]
    return (a < alpha_thresh) | (z < d - depth_margin)


def _uncovered(map_means: torch.Tensor, points: torch.Tensor, footprint: torch.Tensor) -> torch.Tensor:
    """[P] bool: the ``points`` [P,3] with no map centre (``map_means`` [N,3]) within their ``footprint`` [P]
    (metres: one pixel at the point's depth)."""
    r = float(footprint.max())
    # only the centres in the points' box (grown by r) can be that near: the search grid is built over
    # what the small segments' neighbourhood holds, not over the whole map at every keyframe
    means = map_means.detach().float()
    near = ((means >= points.min(0).values - r) & (means <= points.max(0).values + r)).all(1)
    if not bool(near.any()):
        return torch.ones(len(points), dtype=torch.bool, device=points.device)
    _, dist = knn(means[near], points, 1, r)
    return dist[:, 0] > footprint


def _segment_medians(z: torch.Tensor, seg: torch.Tensor, n_seg: int) -> torch.Tensor:
    """[n_seg] the median depth (the lower one for an even count, as ``torch.median``) of each segment's
    probes, from their depths ``z`` [P] and segment indices ``seg`` [P] (-1 = none); 0 without probes."""
    ok = seg >= 0
    zs, ss = z[ok], seg[ok]
    if not len(zs):
        return z.new_zeros(n_seg)
    by_depth = torch.argsort(zs, stable=True)
    ordered = zs[by_depth][torch.argsort(ss[by_depth], stable=True)]  # by segment, then by depth
    counts = torch.bincount(ss, minlength=n_seg)
    lower_mid = torch.cumsum(counts, 0) - counts + (counts - 1).clamp(min=0) // 2
    return torch.where(counts > 0, ordered[lower_mid.clamp(max=len(zs) - 1)], 0.0)


def _dense_pixels(
    frame: Frame, segments: np.ndarray | None, step: int, dense_below: int, min_depth: float, max_depth: float
) -> tuple[np.ndarray, np.ndarray] | None:
    """(rows, cols) of the off-grid valid-depth pixels of the segments that have fewer than ``dense_below``
    grid probes, or None. A book or a light switch a few pixels across gets two or three grid probes: too
    few for its Gaussians to be told from the shelf or the wall around them, in any later view."""
    if segments is None or dense_below <= 0:
        return None
    seg = np.asarray(segments).astype(np.int64)
    d = np.asarray(frame.depth, dtype=np.float32)
    valid = np.isfinite(d) & (d > max(min_depth, 0.0)) & (seg > 0)
    if max_depth > 0:
        valid &= d <= max_depth
    if not valid.any():
        return None
    on_grid = grid_mask(*seg.shape, step)
    n = int(seg.max()) + 1
    probes = np.bincount(seg[valid & on_grid], minlength=n)
    area = np.bincount(seg[valid], minlength=n)
    small = (area > 0) & (probes < dense_below)
    small[0] = False
    extra = valid & ~on_grid & small[np.maximum(seg, 0)]
    if not extra.any():
        return None
    return np.nonzero(extra)


def _probe_segments(
    sid: torch.Tensor, scores: dict[int, float]
) -> tuple[torch.Tensor, torch.Tensor, np.ndarray]:
    """Per probe its segment index (-1 = none) from the segment ids ``sid`` [P] (0 = none); the frame's
    segment ids [S] (on the device) and their raw SAM scores [S] (host: the scores are a dict). Negative ids
    are no segment, as 0 is (``Frame.segments``)."""
    seg_ids, inv = torch.unique(sid.clamp(min=0), return_inverse=True)
    ids = seg_ids.cpu().numpy()  # one small copy: S ids
    # index 0 of the unique ids is "no segment" when present: shift so that it becomes -1
    if ids.size and ids[0] == 0:
        ids, seg_ids, inv = ids[1:], seg_ids[1:], inv - 1
    raw = np.array([float(scores.get(int(i), 1.0)) for i in ids], dtype=np.float32)
    return inv.reshape(-1), seg_ids, raw


def render_coverage(gm: GaussianMap, frame: Frame) -> tuple[torch.Tensor, torch.Tensor] | None:
    """The map rendered at the frame's pose: (alpha [H,W], expected depth [H,W]), the pixels it explains
    (None: an empty map)."""
    if len(gm) == 0:
        return None
    viewmat = torch.as_tensor(np.linalg.inv(frame.pose), dtype=torch.float32, device=gm.device)[None]
    K = torch.as_tensor(frame.K, dtype=torch.float32, device=gm.device)[None]
    gaussians = (gm.means, gm.quats, gm.scales, gm.opacities, gm.colors[:, :1])
    with torch.no_grad():
        depth, alpha, _ = rasterization(*gaussians, viewmat, K, frame.width, frame.height, render_mode="ED")
    return alpha[0, ..., 0], depth[0, ..., 0]
