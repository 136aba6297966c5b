"""Functional rendering API over the Warp kernels (gsplat's argument conventions).

``rasterization`` projects 3D Gaussians (EWA), bins them into 16x16 tiles, sorts each tile front to
back with one 64-bit radix sort, and alpha-blends any number of channels per pixel. Gradients flow to
means, quats, scales, opacities and colors through two autograd Functions: the projection (Warp's
generated adjoint) and the blending (hand-written back-to-front kernel).
"""

from __future__ import annotations

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

RENDER_MODES = ("RGB", "D", "ED", "RGB+D", "RGB+ED")
# Channels blended per kernel pass; wider inputs are blended in chunks (each chunk is its own Warp
# vector type, compiled once).
MAX_CHANNELS_PER_PASS = 32


def _chunks(D: int) -> list[tuple[int, int]]:
    return [(s, min(D, s + MAX_CHANNELS_PER_PASS)) for s in range(0, D, MAX_CHANNELS_PER_PASS)]


def _chunk_inputs(colors, opac, backgrounds, s: int, e: int, vec) -> list:
    """The launch arguments of channels [s, e) that the forward and backward blending kernels share:
    colours, opacities, backgrounds and whether there are any (without, a placeholder the kernel never
    reads: use_background = 0)."""
    C = colors.shape[0]
    bg = backgrounds[:, s:e] if backgrounds is not None else torch.empty(C, e - s, device=colors.device)
    return [
        as_wp(colors[..., s:e].detach(), vec),
        opac,
        as_wp(bg.detach(), vec),
        int(backgrounds is not None),
    ]


class _Rasterize(torch.autograd.Function):
    @staticmethod
    def forward(ctx, means2d, conics, colors, opacities, backgrounds, bins: TileBins, width, height):
        wp = warp_module()
        raster = kernel_modules().raster
        C, N, D = colors.shape
        dev = colors.device
        out_colors = torch.empty(C, height, width, D, device=dev)
        out_alphas = torch.empty(C, height, width, device=dev)
        last_ids = torch.empty(C, height, width, dtype=torch.int32, device=dev)
        # launch arguments shared by every chunk, kept for the backward launches
        geometry = [
            as_wp(means2d.detach(), wp.vec2),
            as_wp(conics.detach(), wp.vec3),
            as_wp(bins.extents, wp.vec2),
        ]
        opac = as_wp(opacities.detach())
        tile_start, isect_ids = as_wp(bins.tile_start), as_wp(bins.isect_ids)
        alphas_arg, last_arg = as_wp(out_alphas), as_wp(last_ids)
        tiles = bins.tiles_x * bins.tiles_y
        layout = [N, width, height, bins.tile_size, bins.tile_threads, bins.tiles_x, tiles]
        with warp_stream(dev) as wdev:
            chunks = _chunks(D)
            for s, e in chunks:
                fwd, _ = raster.raster_kernels(e - s)
                vec = wp.types.vector(length=e - s, dtype=wp.float32)
                # one chunk (D <= 32, the usual case) writes the output in place
                part = out_colors if len(chunks) == 1 else torch.empty(C, height, width, e - s, device=dev)
                wp.launch(
                    fwd,
                    dim=bins.blend_launch_dim,
                    inputs=[
                        *geometry,
                        *_chunk_inputs(colors, opac, backgrounds, s, e, vec),
                        tile_start,
                        as_wp(bins.tile_end),
                        isect_ids,
                        *layout,
                    ],
                    outputs=[as_wp(part, vec), alphas_arg, last_arg],
                    device=wdev,
                    block_dim=raster.BLEND_BLOCK_DIM,
                )
                if part is not out_colors:
                    out_colors[..., s:e] = part
        ctx.wp_args = (geometry, opac, tile_start, isect_ids, alphas_arg, last_arg, layout)
        ctx.save_for_backward(
            means2d,
            conics,
            colors,
            opacities,
            backgrounds if backgrounds is not None else torch.empty(0, device=dev),
            out_alphas,
            last_ids,
        )
        ctx.bins = bins
        ctx.has_bg = backgrounds is not None
        ctx.size = (width, height)
        ctx.mark_non_differentiable(last_ids)
        return out_colors, out_alphas.unsqueeze(-1), last_ids

    @staticmethod
    def backward(ctx, v_colors_out, v_alphas_out, _v_last):
        wp = warp_module()
        raster = kernel_modules().raster
        means2d, conics, colors, opacities, backgrounds, out_alphas, last_ids = ctx.saved_tensors
        bins: TileBins = ctx.bins
        width, height = ctx.size
        C, N, D = colors.shape
        dev = colors.device
        v_means2d = torch.zeros_like(means2d)
        v_conics = torch.zeros_like(conics)
        v_colors = torch.zeros_like(colors)
        v_opac = torch.zeros(C, N, device=dev)
        if v_colors_out is None:
            v_colors_out = torch.zeros(C, height, width, D, device=dev)
        v_alpha = torch.zeros(C, height, width, device=dev) if v_alphas_out is None else v_alphas_out[..., 0]
        geometry, opac, tile_start, isect_ids, alphas_arg, last_arg, layout = ctx.wp_args
        with warp_stream(dev) as wdev:
            chunks = _chunks(D)
            for chunk, (s, e) in enumerate(chunks):
                _, bwd = raster.raster_kernels(e - s)
                vec = wp.types.vector(length=e - s, dtype=wp.float32)
                v_part = v_colors if len(chunks) == 1 else torch.zeros(C, N, e - s, device=dev)
                # The alpha output depends on geometry only: count its gradient in one chunk.
                v_a = v_alpha if chunk == 0 else torch.zeros_like(v_alpha)
                wp.launch(
                    bwd,
                    dim=bins.blend_launch_dim,
                    inputs=[
                        *geometry,
                        *_chunk_inputs(colors, opac, backgrounds if ctx.has_bg else None, s, e, vec),
                        tile_start,
                        isect_ids,
                        alphas_arg,
                        last_arg,
                        as_wp(v_colors_out[..., s:e], vec),
                        as_wp(v_a),
                        *layout,
                    ],
                    outputs=[
                        as_wp(v_means2d, wp.vec2),
                        as_wp(v_conics, wp.vec3),
                        as_wp(v_part, vec),
                        as_wp(v_opac),
                    ],
                    device=wdev,
                    block_dim=raster.BLEND_BLOCK_DIM,
                )
                if v_part is not v_colors:
                    v_colors[..., s:e] = v_part
        v_bg = None
        if ctx.has_bg and ctx.needs_input_grad[4]:
            T = (1.0 - out_alphas).unsqueeze(-1)
            v_bg = (v_colors_out * T).sum(dim=(1, 2))
        return v_means2d, v_conics, v_colors, v_opac.sum(0), v_bg, None, None, None


@on_torch_stream
def rasterization(
    means: torch.Tensor,
    quats: torch.Tensor,
    scales: torch.Tensor,
    opacities: torch.Tensor,
    colors: torch.Tensor,
    viewmats: torch.Tensor,
    Ks: torch.Tensor,
    width: int,
    height: int,
    near_plane: float = 0.01,
    far_plane: float = 1e10,
    backgrounds: torch.Tensor | None = None,
    render_mode: str = "RGB",
    eps2d: float = 0.3,
    tile_size: int = 16,
) -> tuple[torch.Tensor, torch.Tensor, dict]:
    """Rasterize N 3D Gaussians into C views: any number of channels alpha-blended per pixel.

    As gsplat 1.5's ``rasterization`` with its defaults (pinhole, classic mode, radius_clip=0); the math:
    docs/design.md, "Kernel math". Deliberate differences ("Differences from gsplat" there): alpha clamped
    at 0.99 (3DGS, gsplat's main branch); ``meta["radii"]`` [C, N], the larger per-axis radius; always
    unpacked; ``tile_start`` / ``tile_end`` instead of isect_ids / isect_offsets; no SH colours, batch
    dimensions, absgrad, sparse_grad, antialiased mode or other camera models. Differentiable w.r.t.
    means, quats, scales, opacities, colors and viewmats (not Ks). Tensors float32, all on one device.

    Args:
        means: Gaussian centres, world frame. [N, 3]
        quats: rotations, wxyz (need not be unit length). [N, 4]
        scales: activated scales, > 0. [N, 3]
        opacities: activated opacities in [0, 1]. [N]
        colors: the channels to blend, shared by the views or one set per view. [N, D] or [C, N, D]
        viewmats: world-to-camera matrices, OpenCV axes (x right, y down, z forward). [C, 4, 4]
        Ks: pinhole intrinsics, pixel centres at +0.5. [C, 3, 3]
        width: image width in pixels.
        height: image height in pixels.
        near_plane: Gaussians whose centre is not beyond this depth are culled.
        far_plane: Gaussians whose centre is beyond this depth are culled.
        backgrounds: added as T * bg where the Gaussians leave the pixel transparent; None: none. [C, D]
        render_mode: "RGB" (colors), "D" (accumulated depth), "ED" (expected depth = D / alpha),
            "RGB+D" or "RGB+ED" (colors, then depth as the last channel).
        eps2d: added to the 2D covariance's diagonal, in pixels squared (a low-pass filter).
        tile_size: tile side in pixels, 1 to 32.

    Returns:
        A tuple:

        **render_colors**: the blended channels. [C, H, W, D] (D + 1 in "RGB+D" / "RGB+ED", 1 in "D" / "ED")

        **render_alphas**: accumulated opacity. [C, H, W, 1]

        **meta**: gsplat's keys ``radii``, ``means2d`` (``retain_grad()`` it for densification), ``depths``,
        ``conics``, ``opacities``, ``tiles_per_gauss``, ``flatten_ids`` (the sorted intersections'
        c * N + n), ``n_cameras``, ``width``, ``height``, ``tile_size``, ``tile_width``, ``tile_height``;
        and ``tile_start`` / ``tile_end`` [C * tiles] (each tile's range of flatten_ids),
        ``n_intersections``, ``last_ids``.
    """
    checks = ValueChecks()  # settled by the binning's sync
    width, height = check_shapes(means, quats, scales, opacities, viewmats, Ks, width, height)
    tile_size = _check_settings(render_mode, near_plane, far_plane, eps2d, tile_size)
    _check_colors(colors, backgrounds, means, viewmats)
    check_values(checks, means, quats, scales, opacities, viewmats, Ks, colors, backgrounds)
    C, N, D = viewmats.shape[0], means.shape[0], colors.shape[-1]
    if colors.dim() == 2:
        colors = colors.unsqueeze(0).expand(C, N, D)
    means2d, conics, depths, radii, bins = project_and_bin(
        means, quats, scales, opacities, viewmats, Ks, width, height, near_plane, far_plane, eps2d, tile_size,
        checks,
    )  # fmt: skip
    blend, bg = _blend_channels(render_mode, colors, depths, backgrounds)
    render, alphas, last_ids = _Rasterize.apply(
        means2d, conics, blend.contiguous(), opacities, bg, bins, width, height
    )
    if render_mode in ("ED", "RGB+ED"):
        expected = render[..., -1:] / alphas.clamp_min(1e-10)
        render = torch.cat([render[..., :-1], expected], dim=-1)
    projected = {"radii": radii, "means2d": means2d, "depths": depths, "conics": conics}
    return render, alphas, _meta(projected, opacities, bins, last_ids, C, width, height, tile_size)


def _check_settings(
    render_mode: str, near_plane: float, far_plane: float, eps2d: float, tile_size: int
) -> int:
    """The checks of :func:`rasterization`'s settings. -> tile_size."""
    if render_mode not in RENDER_MODES:
        raise ValueError(f"render_mode must be one of {RENDER_MODES}, got {render_mode!r}")
    tile_size = check_int("tile_size", tile_size, 1, 32)
    if not (near_plane > 0 and far_plane > near_plane):
        raise ValueError(
            f"need 0 < near_plane < far_plane, got near_plane={near_plane}, far_plane={far_plane}"
        )
    if not eps2d >= 0:
        raise ValueError(f"eps2d must be >= 0, got {eps2d}")
    return tile_size


def _check_colors(
    colors: torch.Tensor, backgrounds: torch.Tensor | None, means: torch.Tensor, viewmats: torch.Tensor
) -> None:
    """Shape checks of the channels to blend, [N, D] or [C, N, D], and of the backgrounds, [C, D]."""
    dev = means.device
    N, C = means.shape[0], viewmats.shape[0]
    check_tensor("colors", colors, (N, None) if colors.dim() == 2 else (C, N, None), dev, finite=False)
    if colors.shape[-1] == 0:
        raise ValueError("colors must have at least one channel")
    if backgrounds is not None:
        check_tensor("backgrounds", backgrounds, (C, colors.shape[-1]), dev, finite=False)


def _blend_channels(
    render_mode: str, colors: torch.Tensor, depths: torch.Tensor, backgrounds: torch.Tensor | None
) -> tuple[torch.Tensor, torch.Tensor | None]:
    """What ``render_mode`` blends ([C, N, D'] channels) and over which backgrounds (zeros for depth)."""
    if render_mode in ("D", "ED"):
        return depths.unsqueeze(-1), None
    if render_mode in ("RGB+D", "RGB+ED"):
        C = colors.shape[0]
        bg = None if backgrounds is None else torch.cat([backgrounds, backgrounds.new_zeros(C, 1)], dim=-1)
        return torch.cat([colors, depths.unsqueeze(-1)], dim=-1), bg
    return colors, backgrounds


def _meta(
    projected: dict, opacities: torch.Tensor, bins: TileBins, last_ids: torch.Tensor, C: int, width: int,
    height: int, tile_size: int,
) -> dict:  # fmt: skip
    """gsplat's keys where the meaning is the same (its densification strategies read these): not packed,
    so no camera_ids / gaussian_ids. Tiles are ranges [tile_start, tile_end) where gsplat has isect_offsets
    and its int64 sort keys isect_ids."""
    return {
        "camera_ids": None,
        "gaussian_ids": None,
        **projected,
        "opacities": opacities.detach().expand(C, opacities.shape[0]),
        "tiles_per_gauss": bins.tiles_per_gaussian,
        "flatten_ids": bins.isect_ids,
        "tile_start": bins.tile_start,
        "tile_end": bins.tile_end,
        "n_intersections": bins.num_intersections,
        "last_ids": last_ids,
        "n_cameras": C,
        "width": width,
        "height": height,
        "tile_size": tile_size,
        "tile_width": bins.tiles_x,
        "tile_height": bins.tiles_y,
    }


__all__ = ["RENDER_MODES", "MAX_CHANNELS_PER_PASS", "rasterization"]
