"""Tile binning: which 16x16 tiles each projected Gaussian touches, keyed for a per-tile depth sort.

A Gaussian is binned to the tiles of its screen radius's square that its alpha >= 1/255 ellipse meets
(``tile_rect`` bounds them, ``tile_reached`` tests each): elsewhere it would blend nothing, so the images
are those of plain radius binning and the per-tile lists are shorter.

Keys are 64-bit: ``(camera * tiles_per_camera + tile) << 32 | float_bits(depth)``. Depths of kept
Gaussians are > near_plane > 0, and positive IEEE floats order like their bit patterns, so one radix
sort gives tiles in order and, inside each tile, Gaussians front to back.
"""

import warp as wp

from .raster import alpha_extent, ellipse_meets_box, sigma_limit

# a Gaussian's rectangle of at most this many tiles has each tested (a 64-bit mask carries the result)
MASK_TILES = wp.constant(64)


@wp.func
def tile_rect(
    center: wp.vec2, radius: float, ext: wp.vec2, tile_size: int, tiles_x: int, tiles_y: int
) -> wp.vec4i:
    """Tiles [x0, x1) x [y0, y1) of the screen radius's square, bounded as gsplat's isect_tiles does
    (floor((c - r) / ts) to ceil((c + r) / ts): every tile with a pixel centre in [c - r, c + r]), less
    those where the Gaussian's alpha stays below ALPHA_MIN at every pixel centre (outside the
    ``alpha_extent`` box ``ext``): they would blend nothing of it, so the image is the same and the tile
    lists are shorter."""
    ts = float(tile_size)
    # clamped before the int conversion (a radius may reach 1e8 px)
    x0 = int(wp.clamp(wp.floor((center[0] - radius) / ts), 0.0, float(tiles_x)))
    y0 = int(wp.clamp(wp.floor((center[1] - radius) / ts), 0.0, float(tiles_y)))
    x1 = int(wp.clamp(wp.ceil((center[0] + radius) / ts), 0.0, float(tiles_x)))
    y1 = int(wp.clamp(wp.ceil((center[1] + radius) / ts), 0.0, float(tiles_y)))
    if ext[0] < 0.0:
        return wp.vec4i(x0, y0, x0, y0)
    # a tile holds pixel centres in [tx * ts + 0.5, tx * ts + ts - 0.5]: these bounds keep every tile
    # with a centre inside [c - ext, c + ext] (clamped before the int conversion: ext may be huge)
    hx = float(tiles_x)
    hy = float(tiles_y)
    x0 = wp.max(x0, int(wp.clamp(wp.floor((center[0] - ext[0]) / ts), -1.0, hx)))
    y0 = wp.max(y0, int(wp.clamp(wp.floor((center[1] - ext[1]) / ts), -1.0, hy)))
    x1 = wp.max(x0, wp.min(x1, int(wp.clamp(wp.floor((center[0] + ext[0]) / ts), -1.0, hx)) + 1))
    y1 = wp.max(y0, wp.min(y1, int(wp.clamp(wp.floor((center[1] + ext[1]) / ts), -1.0, hy)) + 1))
    return wp.vec4i(x0, y0, x1, y1)


@wp.func
def tile_reached(center: wp.vec2, conic: wp.vec3, t: float, tx: int, ty: int, tile_size: int) -> int:
    """1 if the ellipse sigma <= t (``sigma_limit``) meets tile (tx, ty)'s pixel-centre box, else 0: a
    tile of the bounding box may miss a slanted ellipse."""
    x_lo = float(tx * tile_size) + 0.5
    y_lo = float(ty * tile_size) + 0.5
    box = wp.vec4(x_lo, x_lo + float(tile_size - 1), y_lo, y_lo + float(tile_size - 1))
    return ellipse_meets_box(center, conic, t, box)


@wp.kernel(enable_backward=False)
def count_tiles(
    means2d: wp.array(dtype=wp.vec2),
    radii: wp.array(dtype=wp.int32),
    conics: wp.array(dtype=wp.vec3),
    opacities: wp.array(dtype=float),
    labels: wp.array(dtype=wp.int32),
    confidences: wp.array(dtype=float),
    num_gaussians: int,
    tile_size: int,
    tiles_x: int,
    tiles_y: int,
    counts: wp.array(dtype=wp.int32),
    extents: wp.array(dtype=wp.vec2),
    reached: wp.array(dtype=wp.uint64),
):
    """Tiles per Gaussian; its ``alpha_extent``, for the emission and the blending kernels; and which tiles
    of its ``tile_rect`` its ellipse meets (bit i: the i-th tile in row-major order), so that the emission
    writes exactly the tiles counted here instead of deciding again. A rectangle of more than 64 tiles
    keeps all of them. Where ``labels`` is given (not empty), only voters are binned: a Gaussian of label
    < 0 or confidence <= 0 is culled like one outside the view."""
    tid = wp.tid()
    r = radii[tid]
    if labels.shape[0] > 0:
        n = tid % num_gaussians
        if labels[n] < 0 or confidences[n] <= 0.0:
            r = 0
    if r <= 0:
        counts[tid] = 0
        extents[tid] = wp.vec2(-1.0, -1.0)
        return
    conic = conics[tid]
    t = sigma_limit(opacities[tid % num_gaussians])
    ext = alpha_extent(conic, t)
    extents[tid] = ext
    center = means2d[tid]
    rect = tile_rect(center, float(r), ext, tile_size, tiles_x, tiles_y)
    in_rect = (rect[2] - rect[0]) * (rect[3] - rect[1])
    if in_rect > MASK_TILES:
        counts[tid] = in_rect
        return
    mask = wp.uint64(0)
    bit = wp.uint64(1)
    n = int(0)
    for ty in range(rect[1], rect[3]):
        for tx in range(rect[0], rect[2]):
            if tile_reached(center, conic, t, tx, ty, tile_size) != 0:
                mask = mask | bit
                n += 1
            bit = bit << wp.uint64(1)
    counts[tid] = n
    reached[tid] = mask


@wp.kernel(enable_backward=False)
def emit_intersections(
    means2d: wp.array(dtype=wp.vec2),
    radii: wp.array(dtype=wp.int32),
    extents: wp.array(dtype=wp.vec2),
    reached: wp.array(dtype=wp.uint64),
    depth_bits: wp.array(dtype=wp.int32),
    offsets: wp.array(dtype=wp.int64),
    counts: wp.array(dtype=wp.int32),
    num_gaussians: int,
    tile_size: int,
    tiles_x: int,
    tiles_y: int,
    keys: wp.array(dtype=wp.int64),
    values: wp.array(dtype=wp.int32),
):
    """``offsets`` is the inclusive prefix sum of the per-Gaussian tile ``counts``; the tiles are those
    ``count_tiles`` counted and marked in ``reached``."""
    tid = wp.tid()
    n_tiles = counts[tid]
    if n_tiles == 0:  # culled, or its ellipse meets no tile (``reached`` is unwritten for the culled)
        return
    rect = tile_rect(means2d[tid], float(radii[tid]), extents[tid], tile_size, tiles_x, tiles_y)
    every = (rect[2] - rect[0]) * (rect[3] - rect[1]) > MASK_TILES
    mask = reached[tid]
    cam = tid // num_gaussians
    base = wp.int64(cam * tiles_x * tiles_y)
    k = offsets[tid] - wp.int64(n_tiles)
    low = wp.int64(depth_bits[tid]) & wp.int64(4294967295)
    bit = wp.uint64(1)
    for ty in range(rect[1], rect[3]):
        for tx in range(rect[0], rect[2]):
            if every or (mask & bit) != wp.uint64(0):
                tile = base + wp.int64(ty * tiles_x + tx)
                keys[k] = (tile << wp.int64(32)) | low
                values[k] = tid
                k += wp.int64(1)
            bit = bit << wp.uint64(1)


@wp.kernel(enable_backward=False)
def tile_ranges(
    keys: wp.array(dtype=wp.int64),
    num_isects: int,
    tile_start: wp.array(dtype=wp.int32),
    tile_end: wp.array(dtype=wp.int32),
):
    """Per (camera, tile) the half-open range [start, end) of its entries in the sorted lists."""
    i = wp.tid()
    tile = wp.int32(keys[i] >> wp.int64(32))
    if i == 0:
        tile_start[tile] = 0
    else:
        prev = wp.int32(keys[i - 1] >> wp.int64(32))
        if prev != tile:
            tile_end[prev] = i
            tile_start[tile] = i
    if i == num_isects - 1:
        tile_end[tile] = num_isects
