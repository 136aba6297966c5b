"""New Gaussians ("probes") of a keyframe from its depth and segmentation (paper Sec. III-B.2, first part).

Valid-depth pixels on a regular grid of step ``step`` (so about one probe per ``step**2`` pixels, in every
segment alike) are back-projected to world points. Every probe of a segment takes part in the segment's
KNN association; only the probes whose pixel the current map does not already explain (rendered
alpha below ``alpha_thresh``, or observed depth in front of the rendered depth by more than
``depth_margin``) become new Gaussians. Scale: isotropic, the footprint of one grid cell at that depth
(depth * step / focal), so neighbouring Gaussians overlap; rotation identity; colour from the RGB.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from ..frame import Frame
from .local import rescale_sam_scores


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
    *,
    step: int = 2,
    score_range: tuple[float, float] = (0.88, 1.0),
    conf_range: tuple[float, float] = (0.5, 1.0),
    rendered_alpha: torch.Tensor | None = None,
    rendered_depth: torch.Tensor | None = None,
    alpha_thresh: float = 0.5,
    depth_margin: float = 0.1,
    min_depth: float = 0.0,
    max_depth: float = 0.0,
) -> Probes:
    """Back-project the grid pixels of ``frame`` (must have a pose). ``segments`` int [H,W] (0 = none)
    or None; ``rendered_alpha``/``rendered_depth`` [H,W] from rendering the map at the frame's pose
    (None when the map is empty: every probe is new)."""
    if frame.pose is None:
        raise ValueError(f"frame {frame.index}: no pose; mapping needs camera-to-world poses")
    h, w = frame.height, frame.width
    depth = np.asarray(frame.depth, dtype=np.float32)
    ok = grid_mask(h, w, max(1, int(step))) & np.isfinite(depth) & (depth > max(min_depth, 0.0))
    if max_depth > 0:
        ok &= depth <= max_depth
    vv, uu = np.nonzero(ok)
    z = depth[vv, uu]
    K = frame.K.astype(np.float64)
    x = (uu + 0.5 - K[0, 2]) / K[0, 0] * z
    y = (vv + 0.5 - K[1, 2]) / K[1, 1] * z
    pc = np.stack([x, y, z], 1)
    pw = pc @ frame.pose[:3, :3].T + frame.pose[:3, 3]
    focal = 0.5 * (K[0, 0] + K[1, 1])
    log_s = np.log(np.maximum(z * max(1, int(step)) / focal, 1e-6))
    colors = frame.rgb[vv, uu].astype(np.float32) / 255.0
    pix = vv.astype(np.int64) * w + uu

    if segments is not None:
        sid = np.asarray(segments)[vv, uu].astype(np.int64)
        seg_ids, inv = np.unique(sid, return_inverse=True)
        inv = inv.reshape(-1)
        # index 0 of the unique ids is "no segment" when present: shift so that it becomes -1
        if seg_ids.size and seg_ids[0] == 0:
            seg_ids = seg_ids[1:]
            inv = inv - 1
        seg_ids = seg_ids[seg_ids > 0]
        raw = np.array([float(scores.get(int(i), 1.0)) for i in seg_ids], dtype=np.float32)
    else:
        seg_ids = np.zeros(0, dtype=np.int64)
        inv = np.full(len(z), -1, dtype=np.int64)
        raw = np.zeros(0, dtype=np.float32)

    t = lambda a, dt=torch.float32: torch.as_tensor(np.ascontiguousarray(a), dtype=dt, device=device)  # noqa: E731
    seg = t(inv, torch.int64)
    seg_conf = rescale_sam_scores(t(raw), score_range, conf_range)
    conf = torch.where(
        seg >= 0, seg_conf[seg.clamp(min=0)] if len(seg_ids) else 0.0, torch.zeros_like(seg).float()
    )
    pix_t = t(pix, torch.int64)
    if rendered_alpha is None:
        new = torch.ones(len(z), dtype=torch.bool, device=device)
    else:
        a = rendered_alpha.reshape(-1).to(device)[pix_t]
        d = rendered_depth.reshape(-1).to(device)[pix_t]
        zt = t(z)
        new = (a < alpha_thresh) | (zt < d - depth_margin)
    return Probes(
        means=t(pw),
        colors=t(colors),
        log_scales=t(log_s),
        seg=seg,
        conf=conf.float(),
        new=new,
        pix=pix_t,
        seg_ids=t(seg_ids, torch.int64),
        seg_conf=seg_conf,
    )
