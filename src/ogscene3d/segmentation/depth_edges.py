"""Segment borders moved onto the depth edges they should follow.

A segmenter's mask runs a pixel or two past an object's edge, onto the surface behind it, or stops short of
it, leaving the object's edge pixels in the segment behind: SAM's boundaries are placed on the colour image
and are off by about a pixel, and where the depth camera and the colour camera disagree at an edge the mask
is off by as much again. Each such pixel becomes a Gaussian with the wrong label, at the other surface's
depth, and a small object (a book, a light switch) loses a large share of its Gaussians to it.

A border pixel is moved to the neighbouring segment whose surface its depth continues, where it does not
continue its own: depth along a surface is close to linear over a few pixels, so the depth that two steps
of a segment predict for the next pixel (``2 * d1 - d2``, along an axis or a diagonal) tells whether that
pixel lies on the segment's surface. Its own segment's prediction comes from its interior pixels only, as a
spilled strip of pixels continues itself. A pixel whose own segment is too thin for a prediction (a chair's
leg) stays where it is, and so does one that continues both (two surfaces that meet, as a cup stands on a
table).
"""

from __future__ import annotations

import numpy as np
import torch


def snap_to_depth_edges(
    ids: np.ndarray, depth: np.ndarray, margin: float, rounds: int = 2, device: str | torch.device = "cpu"
) -> np.ndarray:
    """Move the segments' border pixels onto the depth edges (see the module's docstring).

    Args:
        ids: segment id map, int [H, W]; 0 (or less) = no segment, which no pixel moves to or from.
        depth: metres, float [H, W]; 0 or not finite = no depth (such pixels neither move nor predict).
        margin: metres; a pixel moves when its depth is more than ``margin`` off its own segment's
            prediction and less than ``margin`` (and less than half that) off a neighbouring segment's.
        rounds: passes at most; a pass moves a strip's outer pixels, after which the next pixels of a strip
            two pixels wide are on the border.
        device: where the passes run (the mapper's device: a thread per pixel).

    Returns:
        The moved id map (a new array), same shape and dtype as ``ids``.

    Raises:
        ValueError: ``ids`` and ``depth`` differ in shape, ``margin`` is not above 0, or an id does not fit
            in 32 bits.

    Examples:
        >>> ids = np.array([[1, 1, 1, 2, 2, 2]] * 3)
        >>> depth = np.ones((3, 6), np.float32)  # the segments' border follows the depth: nothing moves
        >>> snap_to_depth_edges(ids, depth, 0.05)[0].tolist()
        [1, 1, 1, 2, 2, 2]
        >>> depth[:, 2:] = 2.0  # segment 1 runs one pixel onto the surface behind it
        >>> snap_to_depth_edges(ids, depth, 0.05)[0].tolist()
        [1, 1, 2, 2, 2, 2]
    """
    ids, depth = np.asarray(ids), np.asarray(depth)
    if ids.shape != depth.shape or ids.ndim != 2:
        raise ValueError(f"segment ids {ids.shape} and depth {depth.shape} must be one [H, W] shape")
    if not margin > 0:
        raise ValueError(f"margin must be > 0 metres, got {margin}")
    if not ids.size or rounds < 1:
        return ids.copy()
    big = np.iinfo(np.int32)
    if ids.min() < big.min or ids.max() > big.max:
        raise ValueError(f"segment ids must fit in 32 bits, got {ids.min()}..{ids.max()}")
    import warp as wp

    from ..device import warp_stream
    from ..kernels.depth_edges import launch_snap_round

    dev = torch.device(device)
    cur = torch.tensor(ids, dtype=torch.int32, device=dev)  # a copy: the rounds write into it, never into ids
    d = torch.from_numpy(np.ascontiguousarray(depth, dtype=np.float32)).to(dev)
    nxt = torch.empty_like(cur)
    moved = torch.zeros(1, dtype=torch.int32, device=dev)
    with warp_stream(dev) as wdev:
        wd = wp.from_torch(d)
        for _ in range(rounds):
            moved.zero_()
            launch_snap_round(
                wp.from_torch(cur), wd, float(margin), wp.from_torch(nxt), wp.from_torch(moved), wdev
            )
            cur, nxt = nxt, cur
            if not int(moved.item()):  # a round that moves nothing leaves the next one nothing to do
                break
    return cur.cpu().numpy().astype(ids.dtype, copy=False)
