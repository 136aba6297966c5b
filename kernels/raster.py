"""Per-pixel front-to-back alpha blending of N-channel colours, and its hand-written backward.

The channel count is a compile-time constant (a Warp vector length), so accumulators live in registers;
``raster_kernels(D)`` builds and caches the pair of kernels for D channels. One thread per pixel,
threads of a tile consecutive, so on CUDA the warps of a block walk one tile's Gaussian list together
(reading it 32 Gaussians at a time, see lanes.py). Of each batch a warp broadcasts and evaluates only the
Gaussians that reach one of its pixels (``warp_reaches``: the box the binning computed with
``alpha_extent``, then the alpha >= 1/255 ellipse): a 16x16 tile's list holds every Gaussian that
touches the tile, but one warp covers an 8x4 block of it. The same kernels run on the CPU device, where
a warp is one pixel.
"""

import functools

import warp as wp

from .lanes import (
    bit_clear,
    bit_lowest,
    lane_all,
    lane_any,
    lane_ballot,
    lane_count,
    lane_max_int,
    lane_shfl,
    lane_shfl_int,
    lane_shfl_vec2,
    lane_shfl_vec3,
    lane_sum,
)

# Blending kernels: 256-thread blocks (one 16x16 tile), no grid-stride loop (the launch covers every
# pixel), fast intrinsics for exp and division as gsplat builds with; "unique" gives each channel count /
# buffer size its own module, which module options require.
BLEND_BLOCK_DIM = 256
BLEND_KERNEL_OPTIONS = {
    "enable_backward": False,
    "module": "unique",
    "module_options": {"fast_math": True},
    "launch_bounds": BLEND_BLOCK_DIM,
    "grid_stride": False,
}

ALPHA_MAX = 0.99
ALPHA_MIN = 1.0 / 255.0
T_MIN = 1e-4


@wp.func
def tile_local_xy(local: int, tile_size: int) -> wp.vec2i:
    """Pixel offset in its tile of a tile's ``local``-th thread. Where the tile side is a multiple of 8,
    each 32 consecutive threads (one CUDA warp) cover an 8x4 block: a squarer warp footprint than two
    16-pixel rows, so fewer of the tile's Gaussians reach a warp (see ``warp_reaches``). Otherwise
    rows."""
    if tile_size % 8 == 0:
        w = local // 32
        lane = local - w * 32
        blocks_x = tile_size // 8
        by = w // blocks_x
        return wp.vec2i((w - by * blocks_x) * 8 + lane % 8, by * 4 + lane // 8)
    return wp.vec2i(local % tile_size, local // tile_size)


@wp.func
def tile_pixel(
    tid: int, tile_size: int, tile_threads: int, tiles_x: int, tiles_per_cam: int, width: int, height: int
) -> wp.vec4i:
    """(output pixel index or -1, camera-tile index, x, y) of a tile-major thread id. Each tile has
    ``tile_threads`` threads (tile_size^2 rounded up to whole warps); the spare ones and those past the
    image edge get -1."""
    ct = tid // tile_threads
    local = tid - ct * tile_threads
    cam = ct // tiles_per_cam
    tile = ct - cam * tiles_per_cam
    ty = tile // tiles_x
    tx = tile - ty * tiles_x
    xy = tile_local_xy(local, tile_size)
    x = tx * tile_size + xy[0]
    y = ty * tile_size + xy[1]
    if local >= tile_size * tile_size or x >= width or y >= height:
        return wp.vec4i(-1, ct, x, y)
    return wp.vec4i((cam * height + y) * width + x, ct, x, y)


@wp.func
def warp_rect(
    tid: int, tile_size: int, tile_threads: int, tiles_x: int, tiles_per_cam: int, lanes: int
) -> wp.vec4:
    """(x_lo, x_hi, y_lo, y_hi): the pixel centres spanned by the ``lanes``-thread warp of ``tid`` (the
    thread's own pixel where ``lanes`` is 1). A warp of spare threads (past the tile's pixels) gets an
    empty rectangle: lo > hi on an axis."""
    ct = tid // tile_threads
    local = tid - ct * tile_threads
    tile = ct % tiles_per_cam
    ox = (tile % tiles_x) * tile_size
    oy = (tile // tiles_x) * tile_size
    first = local - local % lanes
    last = wp.min(first + lanes, tile_size * tile_size) - 1
    lo = tile_local_xy(first, tile_size)
    hi = tile_local_xy(last, tile_size)
    if tile_size % 8 != 0 and lo[1] != hi[1]:
        lo[0] = 0  # rows: a warp over several rows spans the tile's width
        hi[0] = tile_size - 1
    return wp.vec4(
        float(ox + lo[0]) + 0.5, float(ox + hi[0]) + 0.5, float(oy + lo[1]) + 0.5, float(oy + hi[1]) + 0.5
    )


@wp.func
def sigma_limit(opacity: float) -> float:
    """t with alpha < ALPHA_MIN wherever sigma > t: ln(opacity / ALPHA_MIN) plus a margin that covers
    fast-math rounding; -1 where the Gaussian blends nowhere."""
    if not (opacity > 0.0):
        return -1.0
    t = wp.log(opacity / ALPHA_MIN) + 0.01
    if t <= 0.0:
        return -1.0
    return t


@wp.func
def alpha_extent(conic: wp.vec3, t: float) -> wp.vec2:
    """Half-widths (x, y) of a box around the 2D mean outside which alpha < ALPHA_MIN.

    alpha >= ALPHA_MIN needs sigma <= t (``sigma_limit`` of the opacity), an ellipse; these are its
    bounding box's half-widths, with a margin that covers fast-math rounding. (-1, -1) where the Gaussian
    blends nowhere (t < 0); infinite for a degenerate conic."""
    if t <= 0.0:
        return wp.vec2(-1.0, -1.0)
    det = conic[0] * conic[2] - conic[1] * conic[1]
    if not (det > 0.0):
        return wp.vec2(wp.inf, wp.inf)
    return wp.vec2(wp.sqrt(2.0 * t * conic[2] / det) + 0.01, wp.sqrt(2.0 * t * conic[0] / det) + 0.01)


@wp.func
def gaussian_reaches(mean2d: wp.vec2, extent: wp.vec2, rect: wp.vec4) -> int:
    """0 if a Gaussian with ``alpha_extent`` ``extent`` has alpha < ALPHA_MIN at every pixel centre of
    ``rect``, else 1. Conservative: a kept Gaussian that blends nothing is skipped per pixel later."""
    if extent[0] < 0.0:
        return 0
    if mean2d[0] + extent[0] < rect[0] or mean2d[0] - extent[0] > rect[1]:
        return 0
    if mean2d[1] + extent[1] < rect[2] or mean2d[1] - extent[1] > rect[3]:
        return 0
    return 1


@wp.func
def ellipse_meets_box(mean2d: wp.vec2, conic: wp.vec3, t: float, box: wp.vec4) -> int:
    """1 if sigma <= t somewhere in ``box`` (x_lo, x_hi, y_lo, y_hi), else 0; 1 for a conic that is not
    positive definite. Exact where ``gaussian_reaches`` tests the ellipse's bounding box."""
    if mean2d[0] >= box[0] and mean2d[0] <= box[1] and mean2d[1] >= box[2] and mean2d[1] <= box[3]:
        return 1
    a = conic[0]
    b = conic[1]
    c = conic[2]
    if not (a > 0.0 and c > 0.0):
        return 1
    # the convex quadratic's minimum over the box lies on an edge: on each, minimise along it (clamped)
    best = float(wp.inf)
    for e in range(4):
        dx = float(0.0)
        dy = float(0.0)
        if e < 2:
            dx = mean2d[0] - box[e]  # the x_lo (e = 0) or x_hi edge
            dy = wp.clamp(-b * dx / c, mean2d[1] - box[3], mean2d[1] - box[2])
        else:
            dy = mean2d[1] - box[e]  # the y_lo (e = 2) or y_hi edge
            dx = wp.clamp(-b * dy / a, mean2d[0] - box[1], mean2d[0] - box[0])
        best = wp.min(best, 0.5 * (a * dx * dx + c * dy * dy) + b * dx * dy)
    if best <= t:
        return 1
    return 0


@wp.func
def warp_reaches(
    mean2d: wp.vec2, conic: wp.vec3, opacity: float, extent: wp.vec2, rect: wp.vec4, lanes: int
) -> int:
    """Whether a Gaussian can blend at one of the warp's pixels (``rect``): its bounding box first, then,
    for a warp of several pixels, the ellipse itself (about an eighth fewer Gaussians evaluated). For a
    one-pixel warp (the CPU) the per-pixel alpha test that follows is that same test."""
    if gaussian_reaches(mean2d, extent, rect) == 0:
        return 0
    if lanes == 1:
        return 1
    return ellipse_meets_box(mean2d, conic, sigma_limit(opacity), rect)


@wp.func
def gaussian_alpha(conic: wp.vec3, mean2d: wp.vec2, opacity: float, px: float, py: float) -> wp.vec3:
    """(alpha, sigma, vis) at pixel centre (px, py); alpha = 0 where the Gaussian is skipped."""
    dx = mean2d[0] - px
    dy = mean2d[1] - py
    sigma = 0.5 * (conic[0] * dx * dx + conic[2] * dy * dy) + conic[1] * dx * dy
    if sigma < 0.0:
        return wp.vec3(0.0, sigma, 0.0)
    vis = wp.exp(-sigma)
    alpha = wp.min(ALPHA_MAX, opacity * vis)
    if alpha < ALPHA_MIN:
        return wp.vec3(0.0, sigma, vis)
    return wp.vec3(alpha, sigma, vis)


@functools.cache
def raster_kernels(channels: int):
    """(forward, backward) blending kernels for ``channels`` colour channels."""
    vec = wp.types.vector(length=channels, dtype=wp.float32)

    @wp.func
    def shfl_vec(v: vec, src: int) -> vec:
        out = vec()
        for ch in range(channels):
            out[ch] = lane_shfl(v[ch], src)
        return out

    @wp.func
    def sum_vec(v: vec) -> vec:
        out = vec()
        for ch in range(channels):
            out[ch] = lane_sum(v[ch])
        return out

    @wp.kernel(**BLEND_KERNEL_OPTIONS)
    def rasterize_forward(
        means2d: wp.array(dtype=wp.vec2),
        conics: wp.array(dtype=wp.vec3),
        extents: wp.array(dtype=wp.vec2),
        colors: wp.array(dtype=vec),
        opacities: wp.array(dtype=float),
        backgrounds: wp.array(dtype=vec),
        use_background: int,
        tile_start: wp.array(dtype=wp.int32),
        tile_end: wp.array(dtype=wp.int32),
        isect_ids: wp.array(dtype=wp.int32),
        num_gaussians: int,
        width: int,
        height: int,
        tile_size: int,
        tile_threads: int,
        tiles_x: int,
        tiles_per_cam: int,
        out_colors: wp.array(dtype=vec),
        out_alphas: wp.array(dtype=float),
        last_ids: wp.array(dtype=wp.int32),
    ):
        tid = wp.tid()
        pix = tile_pixel(tid, tile_size, tile_threads, tiles_x, tiles_per_cam, width, height)
        out = pix[0]
        ct = pix[1]
        cam = ct // tiles_per_cam
        px = float(pix[2]) + 0.5
        py = float(pix[3]) + 0.5
        W = lane_count()
        lane = tid % W
        rect = warp_rect(tid, tile_size, tile_threads, tiles_x, tiles_per_cam, W)
        end = tile_end[ct]
        T = float(1.0)
        acc = vec()
        last = int(-1)
        done = int(0)
        if out < 0:
            done = 1  # pixels past the image edge still take part in the lane shuffles
        b = tile_start[ct]
        while b < end:
            if lane_all(done) != 0:
                break
            # one Gaussian per lane, then each is broadcast to the whole warp in turn
            j = b + lane
            gm = wp.vec2()
            gc = wp.vec3()
            go = float(0.0)
            gcol = vec()
            reaches = int(0)
            if j < end:
                g = isect_ids[j]
                gm = means2d[g]
                gc = conics[g]
                go = opacities[g % num_gaussians]
                reaches = warp_reaches(gm, gc, go, extents[g], rect, W)
                if reaches != 0:
                    gcol = colors[g]  # only a reaching Gaussian's colour is ever broadcast
            # only the batch's Gaussians that reach the warp's pixels are broadcast and evaluated
            pending = lane_ballot(reaches)
            while pending != 0:
                s = bit_lowest(pending)
                pending = bit_clear(pending, s)
                m = lane_shfl_vec2(gm, s)
                con = lane_shfl_vec3(gc, s)
                o = lane_shfl(go, s)
                c = shfl_vec(gcol, s)
                if done == 0:
                    alpha = gaussian_alpha(con, m, o, px, py)[0]
                    if alpha > 0.0:
                        next_T = T * (1.0 - alpha)
                        if next_T <= T_MIN:
                            done = 1
                        else:
                            acc += c * (alpha * T)
                            T = next_T
                            last = b + s
            b += W
        if out >= 0:
            if use_background != 0:
                acc += backgrounds[cam] * T
            out_colors[out] = acc
            out_alphas[out] = 1.0 - T
            last_ids[out] = last

    @wp.kernel(**BLEND_KERNEL_OPTIONS)
    def rasterize_backward(
        means2d: wp.array(dtype=wp.vec2),
        conics: wp.array(dtype=wp.vec3),
        extents: wp.array(dtype=wp.vec2),
        colors: wp.array(dtype=vec),
        opacities: wp.array(dtype=float),
        backgrounds: wp.array(dtype=vec),
        use_background: int,
        tile_start: wp.array(dtype=wp.int32),
        isect_ids: wp.array(dtype=wp.int32),
        out_alphas: wp.array(dtype=float),
        last_ids: wp.array(dtype=wp.int32),
        v_out_colors: wp.array(dtype=vec),
        v_out_alphas: wp.array(dtype=float),
        num_gaussians: int,
        width: int,
        height: int,
        tile_size: int,
        tile_threads: int,
        tiles_x: int,
        tiles_per_cam: int,
        v_means2d: wp.array(dtype=wp.vec2),
        v_conics: wp.array(dtype=wp.vec3),
        v_colors: wp.array(dtype=vec),
        v_opacities: wp.array(dtype=float),
    ):
        """Back to front from the last contributor, undoing the transmittance one Gaussian at a time."""
        tid = wp.tid()
        pix = tile_pixel(tid, tile_size, tile_threads, tiles_x, tiles_per_cam, width, height)
        out = pix[0]
        ct = pix[1]
        cam = ct // tiles_per_cam
        px = float(pix[2]) + 0.5
        py = float(pix[3]) + 0.5
        W = lane_count()
        lane = tid % W
        rect = warp_rect(tid, tile_size, tile_threads, tiles_x, tiles_per_cam, W)
        last = int(-1)
        T_final = float(1.0)
        v_c = vec()
        v_a_out = float(0.0)
        # Blending a background adds T_final * bg, whose derivative w.r.t. each alpha is -T_final/(1-a) * bg.
        bg_dot = float(0.0)
        if out >= 0:
            last = last_ids[out]
            T_final = 1.0 - out_alphas[out]
            v_c = v_out_colors[out]
            v_a_out = v_out_alphas[out]
            if use_background != 0:
                bg_dot = wp.dot(backgrounds[cam], v_c)
        T = T_final
        start = tile_start[ct]
        behind = vec()  # sum over Gaussians behind the current one of c_j * w_j
        b = lane_max_int(last)  # the warp walks back from its furthest last contributor
        while b >= start:
            j = b - lane
            gid = int(-1)
            gm = wp.vec2()
            gc = wp.vec3()
            go = float(0.0)
            gcol = vec()
            reaches = int(0)
            if j >= start:
                gid = isect_ids[j]
                gm = means2d[gid]
                gc = conics[gid]
                go = opacities[gid % num_gaussians]
                reaches = warp_reaches(gm, gc, go, extents[gid], rect, W)
                if reaches != 0:
                    gcol = colors[gid]
            pending = lane_ballot(reaches)  # lane s holds Gaussian b - s: lowest bit first is back to front
            while pending != 0:
                s = bit_lowest(pending)
                pending = bit_clear(pending, s)
                m = lane_shfl_vec2(gm, s)
                con = lane_shfl_vec3(gc, s)
                o = lane_shfl(go, s)
                c = shfl_vec(gcol, s)
                hit = int(0)
                v_col = vec()
                v_con = wp.vec3()
                v_m = wp.vec2()
                v_o = float(0.0)
                if b - s <= last:
                    a = gaussian_alpha(con, m, o, px, py)
                    alpha = a[0]
                    if alpha > 0.0:
                        hit = 1
                        ra = 1.0 / (1.0 - alpha)
                        T = T * ra
                        w = alpha * T
                        v_col = v_c * w
                        v_alpha = wp.dot(c * T - behind * ra, v_c) + (v_a_out - bg_dot) * T_final * ra
                        behind += c * w
                        vis = a[2]
                        if o * vis <= ALPHA_MAX:
                            v_sigma = -o * vis * v_alpha
                            dx = m[0] - px
                            dy = m[1] - py
                            hs = 0.5 * v_sigma
                            v_con = wp.vec3(hs * dx * dx, v_sigma * dx * dy, hs * dy * dy)
                            v_m = wp.vec2(
                                v_sigma * (con[0] * dx + con[1] * dy), v_sigma * (con[1] * dx + con[2] * dy)
                            )
                            v_o = vis * v_alpha
                # one atomic per warp and Gaussian: sum the lanes' gradients first
                if lane_any(hit) != 0:
                    g = lane_shfl_int(gid, s)
                    v_col = sum_vec(v_col)
                    v_con = wp.vec3(lane_sum(v_con[0]), lane_sum(v_con[1]), lane_sum(v_con[2]))
                    v_m = wp.vec2(lane_sum(v_m[0]), lane_sum(v_m[1]))
                    v_o = lane_sum(v_o)
                    if lane == 0:
                        wp.atomic_add(v_colors, g, v_col)
                        wp.atomic_add(v_conics, g, v_con)
                        wp.atomic_add(v_means2d, g, v_m)
                        wp.atomic_add(v_opacities, g, v_o)
            b -= W

    return rasterize_forward, rasterize_backward
