"""Semantic rendering API: confidence-weighted label voting and per-Gaussian rendering contribution.

Both build on the rasterizer's projection and tile binning, restricted to labelled Gaussians
(label >= 0): unlabelled Gaussians neither vote nor occlude (the math: kernels/semantic.py); nor do those
of confidence 0, so they are left out of the tiles too. One kernel launch gives the labels and, for
``rendering_contribution``, P_conf.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import torch

from .._validate import ValueChecks, check_int, check_tensor
from ..device import warp_stream
from ._projection import (
    TileBins,
    as_wp,
    check_shapes,
    check_values,
    kernel_modules,
    on_torch_stream,
    project_and_bin,
    warp_module,
)

DEFAULT_BUFFER_SIZE = 8


@dataclass
class SemanticRender:
    """The label map of :func:`render_semantics` (and of ``rendering_contribution(return_semantics=True)``).

    Attributes:
        labels: each pixel's winning label, -1 where no labelled Gaussian votes. int32 [C, H, W]
        weights: the winning vote max_k R_p[k]. float32 [C, H, W]
        buffer_labels: with ``return_buffer``, each pixel's (label, weight) entries' labels (-1 = empty);
            else None. int32 [C, H, W, B]
        buffer_weights: with ``return_buffer``, those entries' weights; else None. float32 [C, H, W, B]
        meta: ``buffer_size``; ``overflow_pixels`` (pixels that saw more distinct labels than the buffer
            holds) and ``overflow_votes`` (runs of a label's consecutive votes that met a full buffer:
            dropped, or in place of the weakest entry) as 0-dim int64 tensors on the render's device
            (``int()`` reads them; the call itself does not wait for the GPU); ``n_intersections``.
    """

    labels: torch.Tensor
    weights: torch.Tensor
    buffer_labels: torch.Tensor | None = None
    buffer_weights: torch.Tensor | None = None
    meta: dict = field(default_factory=dict)


@dataclass
class _Scene:
    """The labelled Gaussians and the cameras of one semantic render, their shapes checked."""

    means: torch.Tensor
    quats: torch.Tensor
    scales: torch.Tensor
    opacities: torch.Tensor
    labels: torch.Tensor  # int32
    confidences: torch.Tensor
    viewmats: torch.Tensor
    Ks: torch.Tensor
    width: int
    height: int


def _checked_scene(
    means, quats, scales, opacities, labels, confidences, viewmats, Ks, width, height, checks: ValueChecks
) -> _Scene:
    """Shape checks now; the value checks are queued in ``checks`` (settled by the binning's sync)."""
    width, height = check_shapes(means, quats, scales, opacities, viewmats, Ks, width, height)
    N = means.shape[0]
    check_tensor("labels", labels, (N,), means.device, dtypes=(torch.int32, torch.int64))
    check_tensor("confidences", confidences, (N,), means.device, finite=False)
    check_values(checks, means, quats, scales, opacities, viewmats, Ks, confidences=confidences)
    if N and labels.dtype == torch.int64:
        info = torch.iinfo(torch.int32)
        # below int32's range a label would wrap around to another (even a non-negative) one
        checks.fail_if((labels.max() > info.max) | (labels.min() < info.min), "labels must fit in int32")
    return _Scene(means, quats, scales, opacities, labels, confidences, viewmats, Ks, width, height)


@dataclass
class _Outputs:
    """What the semantic kernel writes. It writes every pixel of every output it is given; those not asked
    for get one element. The overflow counters and the sums are accumulated, so zeroed: one allocation
    holds both, the sums as float32 bits (all-zero bits are 0.0), so that one fill launch serves; the
    placeholders the kernel never reads need none."""

    buffer_labels: torch.Tensor  # [C, H, W, B] int32, or [1, B] unless write_buffer
    buffer_weights: torch.Tensor
    labels: torch.Tensor  # [C, H, W] int32
    weights: torch.Tensor
    counters: torch.Tensor  # [2] int64: overflow pixels, overflow votes
    numerator: torch.Tensor  # [max(N, 1)] float32 (contribute), else a [1] placeholder
    denominator: torch.Tensor

    @classmethod
    def allocate(cls, C, height, width, n, buffer_size, write_buffer, contribute, dev) -> _Outputs:
        pixels = (C, height, width)
        buffer_shape = (*(pixels if write_buffer else (1,)), buffer_size)
        zeroed = torch.zeros(2 + (max(n, 1) if contribute else 0), dtype=torch.int64, device=dev)
        sums = zeroed[2:].view(torch.float32).view(2, -1) if contribute else torch.empty(2, 1, device=dev)
        return cls(
            torch.empty(buffer_shape, dtype=torch.int32, device=dev),
            torch.empty(buffer_shape, device=dev),
            torch.empty(pixels, dtype=torch.int32, device=dev),
            torch.empty(pixels, device=dev),
            zeroed[:2],
            sums[0],
            sums[1],
        )


def _render(
    scene: _Scene,
    near_plane: float,
    far_plane: float,
    eps2d: float,
    tile_size: int,
    buffer_size: int,
    checks: ValueChecks,
    write_buffer: bool,
    contribute: bool = False,
    pixel_mask: torch.Tensor | None = None,
):
    """Project every Gaussian, bin the labelled ones and run the semantic kernel (the binning settles
    ``checks``). -> (bins, (buffer labels, buffer weights, labels, weights, overflow counters), numerator,
    denominator); the buffer and the sums are None where not asked for."""
    buffer_size = check_int("buffer_size", buffer_size, 1, 64)
    tile_size = check_int("tile_size", tile_size, 1, 32)
    labels = scene.labels.to(torch.int32)
    with torch.no_grad():
        # unlabelled Gaussians neither vote nor occlude, nor do those of confidence 0 (their conf * alpha is
        # 0): the binning leaves them out of every tile
        means2d, conics, _, _, bins = project_and_bin(
            scene.means, scene.quats, scene.scales, scene.opacities, scene.viewmats, scene.Ks, scene.width,
            scene.height, near_plane, far_plane, eps2d, tile_size, checks, voters=(labels, scene.confidences),
        )  # fmt: skip
    C, n = scene.viewmats.shape[0], scene.means.shape[0]
    out = _Outputs.allocate(
        C, scene.height, scene.width, n, buffer_size, write_buffer, contribute, scene.means.device
    )
    _launch(scene, labels, means2d, conics, bins, out, buffer_size, write_buffer, contribute, pixel_mask)
    buffers = (out.buffer_labels, out.buffer_weights) if write_buffer else (None, None)
    sums = (out.numerator, out.denominator) if contribute else (None, None)
    return bins, (*buffers, out.labels, out.weights, out.counters), *sums


def _launch(
    scene: _Scene,
    labels: torch.Tensor,
    means2d: torch.Tensor,
    conics: torch.Tensor,
    bins: TileBins,
    out: _Outputs,
    buffer_size: int,
    write_buffer: bool,
    contribute: bool,
    pixel_mask: torch.Tensor | None,
) -> None:
    """One launch of the semantic kernel (kernels/semantic.py) over the binned tiles, writing ``out``."""
    wp = warp_module()
    kernels = kernel_modules()
    dev = scene.means.device
    mask = (
        pixel_mask.to(torch.uint8).contiguous()
        if pixel_mask is not None
        else torch.empty(1, dtype=torch.uint8, device=dev)
    )
    veci = wp.types.vector(length=buffer_size, dtype=wp.int32)
    vecf = wp.types.vector(length=buffer_size, dtype=wp.float32)
    inputs = [
        as_wp(means2d, wp.vec2),
        as_wp(conics, wp.vec3),
        as_wp(bins.extents, wp.vec2),
        as_wp(scene.opacities.detach()),
        as_wp(labels),
        as_wp(scene.confidences.detach()),
        as_wp(bins.tile_start),
        as_wp(bins.tile_end),
        as_wp(bins.isect_ids),
        max(scene.means.shape[0], 1),
        scene.width,
        scene.height,
        bins.tile_size,
        bins.tile_threads,
        bins.tiles_x,
        bins.tiles_x * bins.tiles_y,
        int(write_buffer),
        int(contribute),
        as_wp(mask),
        int(pixel_mask is not None),
    ]
    outputs = [
        as_wp(out.buffer_labels, veci),
        as_wp(out.buffer_weights, vecf),
        as_wp(out.labels),
        as_wp(out.weights),
        as_wp(out.counters),
        as_wp(out.numerator),
        as_wp(out.denominator),
    ]
    with warp_stream(dev) as wdev:
        wp.launch(
            kernels.semantic.semantic_kernel(buffer_size),
            dim=bins.blend_launch_dim,
            inputs=inputs,
            outputs=outputs,
            device=wdev,
            block_dim=kernels.raster.BLEND_BLOCK_DIM,
        )


@on_torch_stream
def render_semantics(
    means: torch.Tensor,
    quats: torch.Tensor,
    scales: torch.Tensor,
    opacities: torch.Tensor,
    labels: torch.Tensor,
    confidences: torch.Tensor,
    viewmats: torch.Tensor,
    Ks: torch.Tensor,
    width: int,
    height: int,
    near_plane: float = 0.01,
    far_plane: float = 1e10,
    eps2d: float = 0.3,
    tile_size: int = 16,
    buffer_size: int = DEFAULT_BUFFER_SIZE,
    return_buffer: bool = False,
) -> SemanticRender:
    """Per-pixel label argmax_k R_p[k], R_p[k] = sum_{i: l_i = k} conf_i a_ip prod_{j<i} (1 - conf_j a_jp).

    Only labelled Gaussians (label >= 0, confidence > 0) vote and occlude. Memory is
    O(C * H * W * buffer_size), never O(H * W * number of labels). The projection is
    :func:`rasterization`'s, with the same conventions.

    Args:
        means: Gaussian centres, world frame. [N, 3]
        quats: rotations, wxyz. [N, 4]
        scales: activated scales, > 0. [N, 3]
        opacities: activated opacities in [0, 1]. [N]
        labels: each Gaussian's label, -1 = unlabelled. int32 or int64 [N]
        confidences: each Gaussian's label confidence in [0, 1]. [N]
        viewmats: world-to-camera matrices, OpenCV axes. [C, 4, 4]
        Ks: pinhole intrinsics, pixel centres at +0.5. [C, 3, 3]
        width: image width in pixels.
        height: image height in pixels.
        near_plane: as in :func:`rasterization`.
        far_plane: as in :func:`rasterization`.
        eps2d: as in :func:`rasterization`.
        tile_size: as in :func:`rasterization`.
        buffer_size: distinct labels each pixel keeps votes for, 1 to 64 (the weakest gives way).
        return_buffer: also return every pixel's (label, weight) entries.

    Returns:
        A :class:`SemanticRender`: the label map, the winning votes and (with ``return_buffer``) the buffers.
    """
    checks = ValueChecks()
    scene = _checked_scene(
        means, quats, scales, opacities, labels, confidences, viewmats, Ks, width, height, checks
    )
    bins, outputs, _, _ = _render(
        scene, near_plane, far_plane, eps2d, tile_size, buffer_size, checks, write_buffer=return_buffer
    )
    return _semantic_render(bins, buffer_size, outputs)


@on_torch_stream
def rendering_contribution(
    means: torch.Tensor,
    quats: torch.Tensor,
    scales: torch.Tensor,
    opacities: torch.Tensor,
    labels: torch.Tensor,
    confidences: torch.Tensor,
    viewmat: torch.Tensor,
    K: torch.Tensor,
    width: int,
    height: int,
    pixel_mask: torch.Tensor | None = None,
    eps: float = 1e-6,
    near_plane: float = 0.01,
    far_plane: float = 1e10,
    eps2d: float = 0.3,
    tile_size: int = 16,
    buffer_size: int = DEFAULT_BUFFER_SIZE,
    return_semantics: bool = False,
) -> torch.Tensor | tuple[torch.Tensor, SemanticRender]:
    """Rendering contribution in one view: P_conf(i) = sum_p w_ip R_p[l_i] / (sum_p w_ip + eps).

    The sums run over the pixels of ``pixel_mask`` (all if None); w_ip is the Gaussian's blending weight at
    pixel p and R_p the pixel's votes, as in :func:`render_semantics`. Where a pixel's buffer overflowed,
    R_p of a dropped label is taken as 0 (``SemanticRender.meta`` counts those pixels).

    Args:
        means: as in :func:`render_semantics`.
        quats: as in :func:`render_semantics`.
        scales: as in :func:`render_semantics`.
        opacities: as in :func:`render_semantics`.
        labels: as in :func:`render_semantics`.
        confidences: as in :func:`render_semantics`.
        viewmat: the view's world-to-camera matrix, OpenCV axes. [4, 4] (or [1, 4, 4])
        K: the view's pinhole intrinsics, pixel centres at +0.5. [3, 3] (or [1, 3, 3])
        width: image width in pixels.
        height: image height in pixels.
        pixel_mask: the pixels to sum over; None: all. bool or uint8 [H, W]
        eps: added to the denominator, > 0.
        near_plane: as in :func:`rasterization`.
        far_plane: as in :func:`rasterization`.
        eps2d: as in :func:`rasterization`.
        tile_size: as in :func:`rasterization`.
        buffer_size: as in :func:`render_semantics`.
        return_semantics: also return this view's label map, which the call computes anyway (one call
            instead of ``render_semantics`` + ``rendering_contribution``).

    Returns:
        P_conf, float32 [N] in [0, 1]: 0 for unlabelled Gaussians and those that reach no (masked) pixel.
        With ``return_semantics``, the tuple (P_conf, :class:`SemanticRender` with its buffer).
    """
    if isinstance(viewmat, torch.Tensor) and viewmat.dim() == 2:
        viewmat = viewmat.unsqueeze(0)
    if isinstance(K, torch.Tensor) and K.dim() == 2:
        K = K.unsqueeze(0)
    checks = ValueChecks()
    dev = means.device if isinstance(means, torch.Tensor) else None
    check_tensor("viewmat", viewmat, (1, 4, 4), dev, finite=False)  # values: with the other inputs
    check_tensor("K", K, (1, 3, 3), dev, finite=False)
    scene = _checked_scene(
        means, quats, scales, opacities, labels, confidences, viewmat, K, width, height, checks
    )
    if not eps > 0:
        raise ValueError(f"eps must be > 0, got {eps}")
    if pixel_mask is not None:
        shape = (scene.height, scene.width)
        check_tensor("pixel_mask", pixel_mask, shape, means.device, dtypes=(torch.bool, torch.uint8))
    bins, outputs, num, den = _render(
        scene, near_plane, far_plane, eps2d, tile_size, buffer_size, checks,
        write_buffer=return_semantics, contribute=True, pixel_mask=pixel_mask,
    )  # fmt: skip
    # unlabelled and unseen Gaussians have num = den = 0, hence P_conf 0
    p_conf = (num / (den + eps))[: means.shape[0]].clamp_(0.0, 1.0)
    if not return_semantics:
        return p_conf
    return p_conf, _semantic_render(bins, buffer_size, outputs)


def _semantic_render(bins: TileBins, buffer_size: int, outputs) -> SemanticRender:
    buf_l, buf_w, out_l, out_w, counters = outputs
    # counted by the kernel and left on the device: a host read here would make every call wait for it
    overflow_pixels, overflow_votes = counters.unbind()
    meta = {
        "buffer_size": buffer_size,
        "overflow_pixels": overflow_pixels,
        "overflow_votes": overflow_votes,
        "n_intersections": bins.num_intersections,
    }
    return SemanticRender(
        labels=out_l,
        weights=out_w,
        buffer_labels=buf_l,
        buffer_weights=buf_w,
        meta=meta,
    )


__all__ = ["SemanticRender", "render_semantics", "rendering_contribution"]
