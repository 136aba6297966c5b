"""Functional rendering API over the Warp kernels (gsplat's argument conventions).

``rasterization`` projects 3D Gaussians (EWA), bins them into 16x16 tiles, sorts each tile front to
back with one 64-bit radix sort, and alpha-blends any number of channels per pixel. Gradients flow to
means, quats, scales, opacities and colors through two autograd Functions: the projection (Warp's
generated adjoint) and the blending (hand-written back-to-front kernel).
"""

from __future__ import annotations

import functools
import importlib
import inspect
from dataclasses import dataclass
from typing import Any

import torch

from ._validate import ValueChecks, check_image_size, check_int, check_tensor
from .device import init_warp, warp_stream

RENDER_MODES = ("RGB", "D", "ED", "RGB+D", "RGB+ED")
# Channels blended per kernel pass; wider inputs are blended in chunks (each chunk is its own Warp
# vector type, compiled once).
MAX_CHANNELS_PER_PASS = 32


def _wp():
    return init_warp()


def _kernels():
    from ogscene3d.kernels import binning, projection, raster

    return projection, binning, raster


# torch dtype -> the Warp scalar type a launch argument of that tensor holds
_SCALARS = {
    torch.float32: "float32",
    torch.int32: "int32",
    torch.int64: "int64",
    torch.uint64: "uint64",
    torch.uint8: "uint8",
}


@functools.cache
def _array_descriptor() -> Any:
    """Warp's bare array descriptor type (``warp.types.array_t``; private in newer Warp), or None."""
    wp = _wp()
    found = getattr(wp.types, "array_t", None)
    if found is None:
        try:
            found = importlib.import_module("warp._src.types").array_t
        except (ImportError, AttributeError):
            return None
    return found


@functools.cache
def _item_layout(torch_dtype: torch.dtype, dtype: Any) -> tuple[int, tuple[int, ...]]:
    """(scalars per element, element shape) of a Warp ``dtype`` array (None: the tensor's own scalar type)
    viewing a tensor of ``torch_dtype``; TypeError where the scalar types differ."""
    scalar = _SCALARS.get(torch_dtype)
    expected = getattr(dtype, "_wp_scalar_type_", dtype)
    if scalar is None or (expected is not None and _wp().types.type_repr(expected) != scalar):
        raise TypeError(f"cannot pass a {torch_dtype} tensor as a Warp {dtype} array")
    return getattr(dtype, "_length_", 1), tuple(getattr(dtype, "_shape_", ()))


def _as_wp(t: torch.Tensor, dtype: Any = None):
    """A flat (1D) Warp launch argument viewing a contiguous tensor; vector/matrix dtypes consume the
    trailing dims. It is Warp's bare array descriptor, built directly where Warp exposes its type (a few
    microseconds less than ``wp.from_torch`` per argument, and a forward+backward passes about 60): it
    holds no reference to the memory, so the tensor rides along on it and a contiguous copy lives until
    the launch is queued."""
    t = t.contiguous()
    per_item, shape = _item_layout(t.dtype, dtype)
    if shape and tuple(t.shape[-len(shape) :]) != shape:
        raise TypeError(f"a Warp {dtype} array needs trailing dims {shape}, got a tensor of {tuple(t.shape)}")
    descriptor = _array_descriptor()
    if descriptor is None:
        view = t.reshape(-1, *shape) if shape else t.reshape(-1)
        arg = _wp().from_torch(view, dtype=dtype, requires_grad=False, return_ctype=True)
    else:
        arg = descriptor(t.data_ptr(), 0, 1, (t.numel() // per_item,), (t.element_size() * per_item,))
    arg.tensor = t
    return arg


def _on_torch_stream(fn):
    """Run a public render function inside one ``warp_stream`` (a stream switch costs a few driver calls;
    the entries of its steps then nest for free)."""

    @functools.wraps(fn)
    def wrapper(means, *args, **kwargs):
        if not isinstance(means, torch.Tensor):
            return fn(means, *args, **kwargs)  # its argument checks report the bad input
        with warp_stream(means.device):
            return fn(means, *args, **kwargs)

    return wrapper


class _Project(torch.autograd.Function):
    @staticmethod
    def forward(
        ctx, means, quats, scales, opacities, viewmats, Ks, width, height, near_plane, far_plane, eps2d
    ):
        """``opacities`` (not differentiated here) give gsplat's opacity-aware screen radius (see
        kernels/projection.py)."""
        wp = _wp()
        projection, _, _ = _kernels()
        C, N = viewmats.shape[0], means.shape[0]
        dev = means.device
        # the kernel writes every entry (zeros where it culls)
        means2d = torch.empty(C, N, 2, device=dev)
        conics = torch.empty(C, N, 3, device=dev)
        depths = torch.empty(C, N, device=dev)
        radii = torch.empty(C, N, dtype=torch.int32, device=dev)
        args = [
            means.detach().contiguous(),
            quats.detach().contiguous(),
            scales.detach().contiguous(),
            viewmats.detach().contiguous(),
            Ks.detach().contiguous(),
        ]
        opac = opacities.detach().contiguous()
        inputs = _project_inputs(args, opac, N, width, height, near_plane, far_plane, eps2d)
        if C * N > 0:
            with warp_stream(dev) as wdev:
                wp.launch(
                    projection.project_gaussians,
                    dim=C * N,
                    inputs=inputs,
                    outputs=_project_outputs(means2d, conics, depths, radii),
                    device=wdev,
                )
        ctx.save_for_backward(*args, means2d, conics, depths, radii)
        ctx.wp_inputs = inputs  # descriptors of the saved inputs, reused by the backward launch
        ctx.params = (N, width, height, near_plane, far_plane, eps2d)
        ctx.mark_non_differentiable(radii)
        return means2d, conics, depths, radii

    @staticmethod
    def backward(ctx, v_means2d, v_conics, v_depths, _v_radii):
        wp = _wp()
        projection, _, _ = _kernels()
        means, quats, scales, viewmats, Ks, means2d, conics, depths, radii = ctx.saved_tensors
        N, width, height, near_plane, far_plane, eps2d = ctx.params
        C = viewmats.shape[0]
        v_means = torch.zeros_like(means)
        v_quats = torch.zeros_like(quats)
        v_scales = torch.zeros_like(scales)
        # camera-pose gradients (pose refinement), only when asked: every (camera, Gaussian) thread adds
        # into its camera's one matrix
        v_viewmats = torch.zeros_like(viewmats) if ctx.needs_input_grad[4] else None
        grads_out = [
            torch.zeros_like(means2d) if v_means2d is None else v_means2d.contiguous(),
            torch.zeros_like(conics) if v_conics is None else v_conics.contiguous(),
            torch.zeros_like(depths) if v_depths is None else v_depths.contiguous(),
        ]
        if C * N > 0:
            with warp_stream(means.device) as wdev:
                wp.launch(
                    projection.project_gaussians,
                    dim=C * N,
                    inputs=ctx.wp_inputs,
                    # the adjoint replays the forward, which rewrites its outputs: give it scratch space
                    outputs=_project_outputs(
                        torch.empty_like(means2d),
                        torch.empty_like(conics),
                        torch.empty_like(depths),
                        torch.empty_like(radii),
                    ),
                    adj_inputs=[
                        _as_wp(v_means, wp.vec3),
                        _as_wp(v_quats, wp.vec4),
                        _as_wp(v_scales, wp.vec3),
                        None,
                        None if v_viewmats is None else _as_wp(v_viewmats, wp.mat44),
                        None,
                        0,
                        0,
                        0,
                        0.0,
                        0.0,
                        0.0,
                    ],
                    adj_outputs=[
                        _as_wp(grads_out[0], wp.vec2),
                        _as_wp(grads_out[1], wp.vec3),
                        _as_wp(grads_out[2]),
                        None,
                    ],
                    adjoint=True,
                    device=wdev,
                )
        return v_means, v_quats, v_scales, None, v_viewmats, None, None, None, None, None, None


def _project_inputs(args, opacities, N, width, height, near_plane, far_plane, eps2d):
    wp = _wp()
    means, quats, scales, viewmats, Ks = args
    return [
        _as_wp(means, wp.vec3),
        _as_wp(quats, wp.vec4),
        _as_wp(scales, wp.vec3),
        _as_wp(opacities),
        _as_wp(viewmats, wp.mat44),
        _as_wp(Ks, wp.mat33),
        N,
        width,
        height,
        float(near_plane),
        float(far_plane),
        float(eps2d),
    ]


def _project_outputs(means2d, conics, depths, radii):
    wp = _wp()
    return [_as_wp(means2d, wp.vec2), _as_wp(conics, wp.vec3), _as_wp(depths), _as_wp(radii)]


@dataclass
class TileBins:
    """Tile binning result: per (camera, tile) ranges into the depth-sorted Gaussian id list."""

    tile_size: int
    tiles_x: int
    tiles_y: int
    tile_start: torch.Tensor  # [C * tiles] int32
    tile_end: torch.Tensor  # [C * tiles] int32
    isect_ids: torch.Tensor  # [M] int32, flattened c * N + n, sorted by (camera, tile, depth)
    tiles_per_gaussian: torch.Tensor  # [C, N] int32
    extents: torch.Tensor  # [C, N, 2] half-widths of the box outside which alpha < 1/255; -1 if culled

    @property
    def num_intersections(self) -> int:
        return int(self.isect_ids.shape[0])

    @property
    def tile_threads(self) -> int:
        """Threads per tile in the blending launches: tile_size^2 rounded up to whole 32-lane warps, so
        that no warp spans two tiles (a warp's lanes share the Gaussians they read)."""
        return (self.tile_size * self.tile_size + 31) // 32 * 32

    @property
    def blend_launch_dim(self) -> int:
        return int(self.tile_start.numel()) * self.tile_threads


@functools.cache
def _sort_takes_bit_range() -> bool:
    return "end_bit" in inspect.signature(_wp().utils.radix_sort_pairs).parameters


def _sort_keys(keys, values, count: int, n_tiles: int) -> None:
    """Radix-sort ``count`` (tile << 32 | depth) keys with their values, over the key bits in use only:
    32 depth bits and as many as the largest tile index needs (a 1200x680 image: 44 of 64), where Warp
    takes a bit range."""
    if _sort_takes_bit_range():
        end_bit = 32 + max(1, (n_tiles - 1).bit_length())
        _wp().utils.radix_sort_pairs(keys, values, count, 0, end_bit)
    else:
        _wp().utils.radix_sort_pairs(keys, values, count)


def bin_gaussians(
    means2d: torch.Tensor,
    conics: torch.Tensor,
    opacities: torch.Tensor,
    radii: torch.Tensor,
    depths: torch.Tensor,
    width: int,
    height: int,
    tile_size: int = 16,
    checks: ValueChecks | None = None,
    voters: tuple[torch.Tensor, torch.Tensor] | None = None,
) -> TileBins:
    """Assign projected Gaussians [C, N] to tiles and sort every tile's list front to back.

    A Gaussian goes to the tiles its screen radius covers, less those where its alpha stays below 1/255
    at every pixel (``conics`` [C, N, 3], ``opacities`` [N] decide that), which would blend nothing of it.

    ``checks``: the caller's pending input checks, settled on the sync this function makes anyway.
    ``voters``: (labels [N] int32, confidences [N]) to bin only the Gaussians that vote (label >= 0,
    confidence > 0), as the semantic kernels need (the others neither vote nor occlude)."""
    wp = _wp()
    _, binning, _ = _kernels()
    C, N = radii.shape
    dev = radii.device
    tiles_x = (width + tile_size - 1) // tile_size
    tiles_y = (height + tile_size - 1) // tile_size
    n_tiles = C * tiles_x * tiles_y
    tile_start, tile_end = torch.zeros(2, n_tiles, dtype=torch.int32, device=dev)  # empty tiles: [0, 0)
    counts = torch.empty(C, N, dtype=torch.int32, device=dev)  # count_tiles writes every entry
    extents = torch.empty(C, N, 2, device=dev)  # likewise
    if C * N == 0:
        if checks is not None:
            checks.settle()
        empty = torch.zeros(0, dtype=torch.int32, device=dev)
        return TileBins(tile_size, tiles_x, tiles_y, tile_start, tile_end, empty, counts, extents)
    m2d = _as_wp(means2d.detach(), wp.vec2)
    rad = _as_wp(radii)
    if voters is None:
        voters = (torch.empty(0, dtype=torch.int32, device=dev), torch.empty(0, device=dev))
    footprint = [m2d, rad, _as_wp(conics.detach(), wp.vec3), _as_wp(opacities.detach())]
    votes = [_as_wp(voters[0].to(torch.int32)), _as_wp(voters[1].detach())]
    grid = [N, tile_size, tiles_x, tiles_y]
    ext = _as_wp(extents, wp.vec2)
    # which tiles of its rectangle each Gaussian's ellipse meets, decided once for count and emission
    reached = _as_wp(torch.empty(C * N, dtype=torch.uint64, device=dev))
    with warp_stream(dev) as wdev:
        wp.launch(
            binning.count_tiles,
            dim=C * N,
            inputs=[*footprint, *votes, *grid],
            outputs=[_as_wp(counts), ext, reached],
            device=wdev,
        )
        offsets = torch.cumsum(counts.reshape(-1), 0, dtype=torch.int64)
        # the one host sync: the sort buffers' size (and the verdict of the caller's input checks)
        total = (checks or ValueChecks()).settle(offsets[-1:])[0]
        keys = torch.empty(2 * max(total, 1), dtype=torch.int64, device=dev)
        values = torch.empty(2 * max(total, 1), dtype=torch.int32, device=dev)
        if total > 0:
            depth_bits = depths.detach().contiguous().view(torch.int32)
            wk = _wp().from_torch(keys, requires_grad=False)  # radix_sort_pairs takes wp.arrays
            wv = _wp().from_torch(values, requires_grad=False)
            wp.launch(
                binning.emit_intersections,
                dim=C * N,
                inputs=[m2d, rad, ext, reached, _as_wp(depth_bits), _as_wp(offsets), _as_wp(counts), *grid],
                outputs=[wk, wv],
                device=wdev,
            )
            _sort_keys(wk, wv, total, n_tiles)
            wp.launch(
                binning.tile_ranges,
                dim=total,
                inputs=[wk, total],
                outputs=[_as_wp(tile_start), _as_wp(tile_end)],
                device=wdev,
            )
    return TileBins(tile_size, tiles_x, tiles_y, tile_start, tile_end, values[:total], counts, extents)


def _chunks(D: int) -> list[tuple[int, int]]:
    return [(s, min(D, s + MAX_CHANNELS_PER_PASS)) for s in range(0, D, MAX_CHANNELS_PER_PASS)]


class _Rasterize(torch.autograd.Function):
    @staticmethod
    def forward(ctx, means2d, conics, colors, opacities, backgrounds, bins: TileBins, width, height):
        wp = _wp()
        _, _, raster = _kernels()
        C, N, D = colors.shape
        dev = colors.device
        out_colors = torch.empty(C, height, width, D, device=dev)
        out_alphas = torch.empty(C, height, width, device=dev)
        last_ids = torch.empty(C, height, width, dtype=torch.int32, device=dev)
        # launch arguments shared by every chunk, kept for the backward launches
        geometry = [
            _as_wp(means2d.detach(), wp.vec2),
            _as_wp(conics.detach(), wp.vec3),
            _as_wp(bins.extents, wp.vec2),
        ]
        opac = _as_wp(opacities.detach())
        tile_start, isect_ids = _as_wp(bins.tile_start), _as_wp(bins.isect_ids)
        alphas_arg, last_arg = _as_wp(out_alphas), _as_wp(last_ids)
        tiles = bins.tiles_x * bins.tiles_y
        layout = [N, width, height, bins.tile_size, bins.tile_threads, bins.tiles_x, tiles]
        with warp_stream(dev) as wdev:
            chunks = _chunks(D)
            for s, e in chunks:
                fwd, _ = raster.raster_kernels(e - s)
                vec = wp.types.vector(length=e - s, dtype=wp.float32)
                # one chunk (D <= 32, the usual case) writes the output in place
                part = out_colors if len(chunks) == 1 else torch.empty(C, height, width, e - s, device=dev)
                # without backgrounds the kernel never reads them (use_background = 0)
                bg = backgrounds[:, s:e] if backgrounds is not None else torch.empty(C, e - s, device=dev)
                wp.launch(
                    fwd,
                    dim=bins.blend_launch_dim,
                    inputs=[
                        *geometry,
                        _as_wp(colors[..., s:e].detach(), vec),
                        opac,
                        _as_wp(bg.detach(), vec),
                        int(backgrounds is not None),
                        tile_start,
                        _as_wp(bins.tile_end),
                        isect_ids,
                        *layout,
                    ],
                    outputs=[_as_wp(part, vec), alphas_arg, last_arg],
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
        wp = _wp()
        _, _, raster = _kernels()
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
                bg = backgrounds[:, s:e] if ctx.has_bg else torch.empty(C, e - s, device=dev)
                v_part = v_colors if len(chunks) == 1 else torch.zeros(C, N, e - s, device=dev)
                # The alpha output depends on geometry only: count its gradient in one chunk.
                v_a = v_alpha if chunk == 0 else torch.zeros_like(v_alpha)
                wp.launch(
                    bwd,
                    dim=bins.blend_launch_dim,
                    inputs=[
                        *geometry,
                        _as_wp(colors[..., s:e].detach(), vec),
                        opac,
                        _as_wp(bg.detach(), vec),
                        int(ctx.has_bg),
                        tile_start,
                        isect_ids,
                        alphas_arg,
                        last_arg,
                        _as_wp(v_colors_out[..., s:e], vec),
                        _as_wp(v_a),
                        *layout,
                    ],
                    outputs=[
                        _as_wp(v_means2d, wp.vec2),
                        _as_wp(v_conics, wp.vec3),
                        _as_wp(v_part, vec),
                        _as_wp(v_opac),
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


# kernels/validate.py flag order
_VALUE_MESSAGES = [
    "means contains NaN or inf",
    "quats contains NaN or inf",
    "scales contains NaN or inf",
    "opacities contains NaN or inf",
    "viewmats contains NaN or inf",
    "Ks contains NaN or inf",
    "scales must be positive (activated, e.g. exp(log_scales))",
    "quats contains a zero quaternion",
    "Ks must have positive focal lengths",
    "colors contains NaN or inf",
    "backgrounds contains NaN or inf",
    "confidences contains NaN or inf",
    "confidences must lie in [0, 1]",
]


def _check_shapes(means, quats, scales, opacities, viewmats, Ks, width, height):
    """Shape, dtype and device checks (no device work); the values are checked by ``_check_values``."""
    check_tensor("means", means, (None, 3), finite=False)
    dev = means.device
    N = means.shape[0]
    check_tensor("quats", quats, (N, 4), dev, finite=False)
    check_tensor("scales", scales, (N, 3), dev, finite=False)
    check_tensor("opacities", opacities, (N,), dev, finite=False)
    check_tensor("viewmats", viewmats, (None, 4, 4), dev, finite=False)
    C = viewmats.shape[0]
    check_tensor("Ks", Ks, (C, 3, 3), dev, finite=False)
    if C == 0:
        raise ValueError("viewmats must hold at least one camera, got shape [0, 4, 4]")
    return check_image_size(width, height)


def _check_values(
    checks: ValueChecks,
    means,
    quats,
    scales,
    opacities,
    viewmats,
    Ks,
    colors=None,
    backgrounds=None,
    confidences=None,
) -> None:
    """Queue every value check of the rendering inputs (one kernel); ``checks`` settles them later."""
    wp = _wp()
    from ogscene3d.kernels import validate

    dev = means.device
    flags = torch.zeros(validate.NUM_FLAGS, dtype=torch.int32, device=dev)
    none = torch.zeros(0, device=dev)
    flat = [t.detach() if t is not None else none for t in (colors, backgrounds, confidences)]
    dim = max(means.shape[0], viewmats.shape[0], *(t.numel() for t in flat))
    with warp_stream(dev) as wdev:
        wp.launch(
            validate.check_inputs,
            dim=max(dim, 1),
            inputs=[
                _as_wp(means.detach(), wp.vec3),
                _as_wp(quats.detach(), wp.vec4),
                _as_wp(scales.detach(), wp.vec3),
                _as_wp(opacities.detach()),
                _as_wp(viewmats.detach(), wp.mat44),
                _as_wp(Ks.detach(), wp.mat33),
                *(_as_wp(t) for t in flat),
            ],
            outputs=[_as_wp(flags)],
            device=wdev,
        )
    checks.fail_if_flags(flags, _VALUE_MESSAGES)


@_on_torch_stream
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
    """Render C views of N Gaussians.

    Args (float32, all on one device; quats wxyz, scales and opacities already activated):
        means [N, 3], quats [N, 4], scales [N, 3], opacities [N], colors [N, D] or [C, N, D],
        viewmats [C, 4, 4] world-to-camera (OpenCV axes), Ks [C, 3, 3], backgrounds [C, D] or None.
        render_mode: "RGB" (colors), "D" (accumulated depth), "ED" (expected depth = D / alpha),
        "RGB+D", "RGB+ED" (depth appended as the last channel).
    Returns:
        colors [C, H, W, D] (+1 channel with depth in the "+D"/"+ED" modes, D = 1 in "D"/"ED"),
        alphas [C, H, W, 1], meta (projection and binning results under gsplat's names: radii [C, N] (the
        larger of gsplat's per-axis radii, see below), means2d
        (retain_grad() it for densification), depths, conics, opacities, tiles_per_gauss, flatten_ids (the
        sorted intersections' c * N + n), n_cameras, width, height, tile_size, tile_width, tile_height;
        and ours: tile_start / tile_end [C * tiles] (each tile's range of flatten_ids), n_intersections,
        last_ids).
    Differentiable w.r.t. means, quats, scales, opacities, colors and viewmats (camera poses, as in gsplat;
    not Ks).

    As gsplat 1.5's ``rasterization`` with its defaults (pinhole, rasterize_mode="classic", radius_clip=0):
    EWA projection with the Jacobian's x/z, y/z clamped to the view +- 0.3 tan(fov), eps2d on the 2D
    covariance's diagonal, culled where det <= 0, z outside (near, far), opacity < 1/255 or the screen
    radius box off the image; that box is gsplat's opacity-aware one, per axis
    ceil(min(3.33, sqrt(2 ln(255 o))) * sqrt(cov2d_ii)), i.e. the alpha >= 1/255 ellipse's, and the tiles
    are bounded as gsplat's isect_tiles does, so every pixel where alpha >= 1/255 is blended. Pixel
    centres at +0.5; alpha = min(0.99, o exp(-sigma)), skipped where sigma < 0 or alpha < 1/255; a Gaussian
    that would take the transmittance to <= 1e-4 is not blended and ends the pixel; background added as
    T * bg (zeros for the depth channel); "ED" divides by alpha clamped at 1e-10. Deliberate differences:
    alpha is clamped at 0.99 as in 3DGS and gsplat's main branch (its 1.5.3 release and earlier clamp at
    0.999); radii are [C, N], the larger of gsplat's two per-axis radii (gsplat: [C, N, 2]), so
    ``radii > 0`` marks the same Gaussians as gsplat's ``(radii > 0).all(-1)``; always unpacked (gsplat
    defaults to packed=True, whose meta holds [nnz] entries and camera_ids / gaussian_ids: the images are
    the same); no isect_ids / isect_offsets (tile_start / tile_end instead), no SH colours, batch
    dimensions, absgrad, sparse_grad, antialiased mode or other camera models; a Gaussian whose 2D
    determinant overflows float32 is culled; a Gaussian exactly at z = near_plane is culled (as gsplat's
    torch reference does; its CUDA kernel keeps it).
    """
    width, height = _check_shapes(means, quats, scales, opacities, viewmats, Ks, width, height)
    if render_mode not in RENDER_MODES:
        raise ValueError(f"render_mode must be one of {RENDER_MODES}, got {render_mode!r}")
    tile_size = check_int("tile_size", tile_size, 1, 32)
    if not (near_plane > 0 and far_plane > near_plane):
        raise ValueError(
            f"need 0 < near_plane < far_plane, got near_plane={near_plane}, far_plane={far_plane}"
        )
    if not eps2d >= 0:
        raise ValueError(f"eps2d must be >= 0, got {eps2d}")
    dev = means.device
    N, C = means.shape[0], viewmats.shape[0]
    check_tensor("colors", colors, (N, None) if colors.dim() == 2 else (C, N, None), dev, finite=False)
    if colors.shape[-1] == 0:
        raise ValueError("colors must have at least one channel")
    D = colors.shape[-1]
    if backgrounds is not None:
        check_tensor("backgrounds", backgrounds, (C, D), dev, finite=False)
    checks = ValueChecks()
    _check_values(checks, means, quats, scales, opacities, viewmats, Ks, colors, backgrounds)
    if colors.dim() == 2:
        colors = colors.unsqueeze(0).expand(C, N, D)

    means2d, conics, depths, radii = _Project.apply(
        means, quats, scales, opacities, viewmats, Ks, width, height, near_plane, far_plane, eps2d
    )
    with torch.no_grad():
        # settles checks
        bins = bin_gaussians(means2d, conics, opacities, radii, depths, width, height, tile_size, checks)

    if render_mode in ("D", "ED"):
        blend, bg = depths.unsqueeze(-1), None
    elif render_mode in ("RGB+D", "RGB+ED"):
        blend = torch.cat([colors, depths.unsqueeze(-1)], dim=-1)
        bg = None if backgrounds is None else torch.cat([backgrounds, backgrounds.new_zeros(C, 1)], dim=-1)
    else:
        blend, bg = colors, backgrounds
    render, alphas, last_ids = _Rasterize.apply(
        means2d, conics, blend.contiguous(), opacities, bg, bins, width, height
    )
    if render_mode in ("ED", "RGB+ED"):
        expected = render[..., -1:] / alphas.clamp_min(1e-10)
        render = torch.cat([render[..., :-1], expected], dim=-1)
    # gsplat's keys where the meaning is the same (its densification strategies read these): not packed,
    # so no camera_ids / gaussian_ids. Tiles are ranges [tile_start, tile_end) where gsplat has isect_offsets
    # and its int64 sort keys isect_ids
    meta = {
        "camera_ids": None,
        "gaussian_ids": None,
        "radii": radii,
        "means2d": means2d,
        "depths": depths,
        "conics": conics,
        "opacities": opacities.detach().expand(C, N),
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
    return render, alphas, meta


# The semantic half of the functional API lives in its own module; the design names render.py as the home
# of all three functions, so they are importable from here too (imported last: semantics uses this module).
from .semantics import SemanticRender, render_semantics, rendering_contribution  # noqa: E402

__all__ = [
    "TileBins",
    "bin_gaussians",
    "rasterization",
    "render_semantics",
    "rendering_contribution",
    "SemanticRender",
]
