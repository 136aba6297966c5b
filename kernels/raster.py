"""Per-pixel front-to-back alpha blending of N-channel colours, and its hand-written backward.

The channel count is a compile-time constant (a Warp vector length), so accumulators live in registers;
``raster_kernels(D)`` builds and caches the pair of kernels for D channels. One thread per pixel,
threads of a 16x16 tile consecutive, so on CUDA a thread block walks one tile's Gaussian list together.
The same kernels run on the CPU device.
"""

import functools

import warp as wp

ALPHA_MAX = 0.99
ALPHA_MIN = 1.0 / 255.0
T_MIN = 1e-4


@wp.func
def tile_pixel(
    tid: int, tile_size: int, tiles_x: int, tiles_per_cam: int, width: int, height: int
) -> wp.vec4i:
    """(output pixel index or -1 outside the image, camera-tile index, x, y) of a tile-major thread id."""
    per_tile = tile_size * tile_size
    ct = tid // per_tile
    local = tid - ct * per_tile
    cam = ct // tiles_per_cam
    tile = ct - cam * tiles_per_cam
    ty = tile // tiles_x
    tx = tile - ty * tiles_x
    x = tx * tile_size + local % tile_size
    y = ty * tile_size + local // tile_size
    if x >= width or y >= height:
        return wp.vec4i(-1, ct, x, y)
    return wp.vec4i((cam * height + y) * width + x, ct, x, y)


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

    @wp.kernel(enable_backward=False, module="unique")
    def rasterize_forward(
        means2d: wp.array(dtype=wp.vec2),
        conics: wp.array(dtype=wp.vec3),
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
        tiles_x: int,
        tiles_per_cam: int,
        out_colors: wp.array(dtype=vec),
        out_alphas: wp.array(dtype=float),
        last_ids: wp.array(dtype=wp.int32),
    ):
        pix = tile_pixel(wp.tid(), tile_size, tiles_x, tiles_per_cam, width, height)
        out = pix[0]
        if out < 0:
            return
        ct = pix[1]
        cam = ct // tiles_per_cam
        px = float(pix[2]) + 0.5
        py = float(pix[3]) + 0.5
        T = float(1.0)
        acc = vec()
        last = int(-1)
        for i in range(tile_start[ct], tile_end[ct]):
            g = isect_ids[i]
            a = gaussian_alpha(conics[g], means2d[g], opacities[g % num_gaussians], px, py)
            alpha = a[0]
            if alpha > 0.0:
                next_T = T * (1.0 - alpha)
                if next_T <= T_MIN:
                    break
                acc += colors[g] * (alpha * T)
                T = next_T
                last = i
        if use_background != 0:
            acc += backgrounds[cam] * T
        out_colors[out] = acc
        out_alphas[out] = 1.0 - T
        last_ids[out] = last

    @wp.kernel(enable_backward=False, module="unique")
    def rasterize_backward(
        means2d: wp.array(dtype=wp.vec2),
        conics: wp.array(dtype=wp.vec3),
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
        tiles_x: int,
        tiles_per_cam: int,
        v_means2d: wp.array(dtype=wp.vec2),
        v_conics: wp.array(dtype=wp.vec3),
        v_colors: wp.array(dtype=vec),
        v_opacities: wp.array(dtype=float),
    ):
        """Back to front from the last contributor, undoing the transmittance one Gaussian at a time."""
        pix = tile_pixel(wp.tid(), tile_size, tiles_x, tiles_per_cam, width, height)
        out = pix[0]
        if out < 0:
            return
        ct = pix[1]
        cam = ct // tiles_per_cam
        last = last_ids[out]
        if last < 0:
            return
        px = float(pix[2]) + 0.5
        py = float(pix[3]) + 0.5
        T_final = 1.0 - out_alphas[out]
        T = T_final
        v_c = v_out_colors[out]
        v_a_out = v_out_alphas[out]
        # Blending a background adds T_final * bg, whose derivative w.r.t. each alpha is -T_final/(1-a) * bg.
        bg_dot = float(0.0)
        if use_background != 0:
            bg_dot = wp.dot(backgrounds[cam], v_c)
        behind = vec()  # sum over Gaussians behind the current one of c_j * w_j
        for k in range(last - tile_start[ct] + 1):
            i = last - k
            g = isect_ids[i]
            conic = conics[g]
            m = means2d[g]
            n = g % num_gaussians
            o = opacities[n]
            a = gaussian_alpha(conic, m, o, px, py)
            alpha = a[0]
            if alpha > 0.0:
                ra = 1.0 / (1.0 - alpha)
                T = T * ra
                w = alpha * T
                c = colors[g]
                wp.atomic_add(v_colors, g, v_c * w)
                v_alpha = wp.dot(c * T - behind * ra, v_c) + (v_a_out - bg_dot) * T_final * ra
                behind += c * w
                vis = a[2]
                if o * vis <= ALPHA_MAX:
                    v_sigma = -o * vis * v_alpha
                    dx = m[0] - px
                    dy = m[1] - py
                    wp.atomic_add(
                        v_conics,
                        g,
                        wp.vec3(0.5 * v_sigma * dx * dx, v_sigma * dx * dy, 0.5 * v_sigma * dy * dy),
                    )
                    wp.atomic_add(
                        v_means2d,
                        g,
                        wp.vec2(
                            v_sigma * (conic[0] * dx + conic[1] * dy),
                            v_sigma * (conic[1] * dx + conic[2] * dy),
                        ),
                    )
                    wp.atomic_add(v_opacities, g, vis * v_alpha)

    return rasterize_forward, rasterize_backward
