"""Projection of 3D Gaussians to 2D (EWA) and their binning into screen tiles: the steps the colour
rasterizer (``_rasterization``) and the semantic renderer (``_semantics``) share, with the Warp interop
(torch tensors as Warp arrays, on torch's stream) and the input checks both run.
"""

from __future__ import annotations

import functools
import importlib
import inspect
from dataclasses import dataclass
from typing import Any

import torch

from .._validate import ValueChecks, check_image_size, check_tensor
from ..device import init_warp, warp_stream


def warp_module():
    return init_warp()


@dataclass(frozen=True)
class KernelModules:
    projection: Any
    binning: Any
    raster: Any
    semantic: Any
    validate: Any


@functools.cache
def kernel_modules() -> KernelModules:
    """The Warp kernel modules the renderers launch, imported on first use: they import Warp, which
    importing the renderers (and the mapping, which imports them) does not load."""
    from ogscene3d.kernels import binning, projection, raster, semantic, validate

    return KernelModules(projection, binning, raster, semantic, validate)


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
    wp = warp_module()
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
    if scalar is None or (expected is not None and warp_module().types.type_repr(expected) != scalar):
        raise TypeError(f"cannot pass a {torch_dtype} tensor as a Warp {dtype} array")
    return getattr(dtype, "_length_", 1), tuple(getattr(dtype, "_shape_", ()))


def as_wp(t: torch.Tensor, dtype: Any = None):
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
        arg = warp_module().from_torch(view, dtype=dtype, requires_grad=False, return_ctype=True)
    else:
        arg = descriptor(t.data_ptr(), 0, 1, (t.numel() // per_item,), (t.element_size() * per_item,))
    arg.tensor = t
    return arg


def on_torch_stream(fn):
    """Run a public render function inside one ``warp_stream`` (a stream switch costs a few driver calls;
    the entries of its steps then nest for free)."""

    @functools.wraps(fn)
    def wrapper(means, *args, **kwargs):
        if not isinstance(means, torch.Tensor):
            return fn(means, *args, **kwargs)  # its argument checks report the bad input
        with warp_stream(means.device):
            return fn(means, *args, **kwargs)

    return wrapper


class Project(torch.autograd.Function):
    @staticmethod
    def forward(
        ctx, means, quats, scales, opacities, viewmats, Ks, width, height, near_plane, far_plane, eps2d
    ):
        """``opacities`` (not differentiated here) give gsplat's opacity-aware screen radius (see
        kernels/projection.py)."""
        wp = warp_module()
        projection = kernel_modules().projection
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
        wp = warp_module()
        projection = kernel_modules().projection
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
                        as_wp(v_means, wp.vec3),
                        as_wp(v_quats, wp.vec4),
                        as_wp(v_scales, wp.vec3),
                        None,
                        None if v_viewmats is None else as_wp(v_viewmats, wp.mat44),
                        None,
                        0,
                        0,
                        0,
                        0.0,
                        0.0,
                        0.0,
                    ],
                    adj_outputs=[
                        as_wp(grads_out[0], wp.vec2),
                        as_wp(grads_out[1], wp.vec3),
                        as_wp(grads_out[2]),
                        None,
                    ],
                    adjoint=True,
                    device=wdev,
                )
        return v_means, v_quats, v_scales, None, v_viewmats, None, None, None, None, None, None


def _project_inputs(args, opacities, N, width, height, near_plane, far_plane, eps2d):
    wp = warp_module()
    means, quats, scales, viewmats, Ks = args
    return [
        as_wp(means, wp.vec3),
        as_wp(quats, wp.vec4),
        as_wp(scales, wp.vec3),
        as_wp(opacities),
        as_wp(viewmats, wp.mat44),
        as_wp(Ks, wp.mat33),
        N,
        width,
        height,
        float(near_plane),
        float(far_plane),
        float(eps2d),
    ]


def _project_outputs(means2d, conics, depths, radii):
    wp = warp_module()
    return [as_wp(means2d, wp.vec2), as_wp(conics, wp.vec3), as_wp(depths), as_wp(radii)]


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
    return "end_bit" in inspect.signature(warp_module().utils.radix_sort_pairs).parameters


def _sort_keys(keys, values, count: int, n_tiles: int) -> None:
    """Radix-sort ``count`` (tile << 32 | depth) keys with their values, over the key bits in use only:
    32 depth bits and as many as the largest tile index needs (a 1200x680 image: 44 of 64), where Warp
    takes a bit range."""
    if _sort_takes_bit_range():
        end_bit = 32 + max(1, (n_tiles - 1).bit_length())
        warp_module().utils.radix_sort_pairs(keys, values, count, 0, end_bit)
    else:
        warp_module().utils.radix_sort_pairs(keys, values, count)


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
    wp = warp_module()
    binning = kernel_modules().binning
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
    m2d = as_wp(means2d.detach(), wp.vec2)
    rad = as_wp(radii)
    if voters is None:
        voters = (torch.empty(0, dtype=torch.int32, device=dev), torch.empty(0, device=dev))
    footprint = [m2d, rad, as_wp(conics.detach(), wp.vec3), as_wp(opacities.detach())]
    votes = [as_wp(voters[0].to(torch.int32)), as_wp(voters[1].detach())]
    grid = [N, tile_size, tiles_x, tiles_y]
    ext = as_wp(extents, wp.vec2)
    # which tiles of its rectangle each Gaussian's ellipse meets, decided once for count and emission
    reached = as_wp(torch.empty(C * N, dtype=torch.uint64, device=dev))
    with warp_stream(dev) as wdev:
        wp.launch(
            binning.count_tiles,
            dim=C * N,
            inputs=[*footprint, *votes, *grid],
            outputs=[as_wp(counts), ext, reached],
            device=wdev,
        )
        offsets = torch.cumsum(counts.reshape(-1), 0, dtype=torch.int64)
        # the one host sync: the sort buffers' size (and the verdict of the caller's input checks)
        total = (checks or ValueChecks()).settle(offsets[-1:])[0]
        keys = torch.empty(2 * max(total, 1), dtype=torch.int64, device=dev)
        values = torch.empty(2 * max(total, 1), dtype=torch.int32, device=dev)
        if total > 0:
            depth_bits = depths.detach().contiguous().view(torch.int32)
            wk = warp_module().from_torch(keys, requires_grad=False)  # radix_sort_pairs takes wp.arrays
            wv = warp_module().from_torch(values, requires_grad=False)
            wp.launch(
                binning.emit_intersections,
                dim=C * N,
                inputs=[m2d, rad, ext, reached, as_wp(depth_bits), as_wp(offsets), as_wp(counts), *grid],
                outputs=[wk, wv],
                device=wdev,
            )
            _sort_keys(wk, wv, total, n_tiles)
            wp.launch(
                binning.tile_ranges,
                dim=total,
                inputs=[wk, total],
                outputs=[as_wp(tile_start), as_wp(tile_end)],
                device=wdev,
            )
    return TileBins(tile_size, tiles_x, tiles_y, tile_start, tile_end, values[:total], counts, extents)


def project_and_bin(
    means: torch.Tensor,
    quats: torch.Tensor,
    scales: torch.Tensor,
    opacities: torch.Tensor,
    viewmats: torch.Tensor,
    Ks: torch.Tensor,
    width: int,
    height: int,
    near_plane: float,
    far_plane: float,
    eps2d: float,
    tile_size: int,
    checks: ValueChecks,
    voters: tuple[torch.Tensor, torch.Tensor] | None = None,
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor, TileBins]:
    """The step both renderers start with: project every Gaussian into every camera (differentiable where
    autograd records) and bin them into tiles (``voters``: only those, see :func:`bin_gaussians`), which
    settles the pending input ``checks``. -> (means2d, conics, depths, radii, bins)."""
    means2d, conics, depths, radii = Project.apply(
        means, quats, scales, opacities, viewmats, Ks, width, height, near_plane, far_plane, eps2d
    )
    with torch.no_grad():
        bins = bin_gaussians(
            means2d, conics, opacities, radii, depths, width, height, tile_size, checks, voters
        )
    return means2d, conics, depths, radii, bins


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


def check_shapes(means, quats, scales, opacities, viewmats, Ks, width, height):
    """Shape, dtype and device checks (no device work); the values are checked by ``check_values``."""
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


def check_values(
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
    wp = warp_module()
    validate = kernel_modules().validate
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
                as_wp(means.detach(), wp.vec3),
                as_wp(quats.detach(), wp.vec4),
                as_wp(scales.detach(), wp.vec3),
                as_wp(opacities.detach()),
                as_wp(viewmats.detach(), wp.mat44),
                as_wp(Ks.detach(), wp.mat33),
                *(as_wp(t) for t in flat),
            ],
            outputs=[as_wp(flags)],
            device=wdev,
        )
    checks.fail_if_flags(flags, _VALUE_MESSAGES)
