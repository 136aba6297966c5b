"""Confidence-weighted semantic voting (paper Eq. 3) and per-Gaussian rendering contribution (Eqs. 12-15).

Only labelled Gaussians are binned (the caller projects the labelled subset), so unlabelled ones
neither vote nor occlude. Front to back, a Gaussian's effective opacity is conf * alpha:
    w_ip = conf_i * alpha_ip * prod_{j<i} (1 - conf_j * alpha_jp),   R_p[k] = sum_{i: l_i = k} w_ip.
Labels are unbounded ints, so each pixel keeps a bounded (label, weight) buffer in registers instead of
a K-vector: exact while a pixel sees at most ``buffer_size`` distinct labels. When a new label arrives
at a full buffer, the weakest entry (the new vote included) is dropped and the event is counted.
"""

import functools

import warp as wp

from .raster import T_MIN, gaussian_alpha, tile_pixel


@functools.cache
def semantic_kernels(buffer_size: int):
    """(vote, contribution) kernels for a per-pixel buffer of ``buffer_size`` entries."""
    veci = wp.types.vector(length=buffer_size, dtype=wp.int32)
    vecf = wp.types.vector(length=buffer_size, dtype=wp.float32)

    @wp.kernel(enable_backward=False, module="unique")
    def semantic_vote(
        means2d: wp.array(dtype=wp.vec2),
        conics: wp.array(dtype=wp.vec3),
        opacities: wp.array(dtype=float),
        labels: wp.array(dtype=wp.int32),
        confidences: wp.array(dtype=float),
        tile_start: wp.array(dtype=wp.int32),
        tile_end: wp.array(dtype=wp.int32),
        isect_ids: wp.array(dtype=wp.int32),
        num_gaussians: int,
        width: int,
        height: int,
        tile_size: int,
        tiles_x: int,
        tiles_per_cam: int,
        buf_labels: wp.array(dtype=veci),
        buf_weights: wp.array(dtype=vecf),
        out_labels: wp.array(dtype=wp.int32),
        out_weights: wp.array(dtype=float),
        overflows: wp.array(dtype=wp.int32),
    ):
        pix = tile_pixel(wp.tid(), tile_size, tiles_x, tiles_per_cam, width, height)
        out = pix[0]
        if out < 0:
            return
        ct = pix[1]
        px = float(pix[2]) + 0.5
        py = float(pix[3]) + 0.5
        T = float(1.0)
        labs = veci(-1)
        ws = vecf(0.0)
        filled = int(0)
        dropped = int(0)
        for i in range(tile_start[ct], tile_end[ct]):
            g = isect_ids[i]
            n = g % num_gaussians
            a = gaussian_alpha(conics[g], means2d[g], opacities[n], px, py)
            ca = confidences[n] * a[0]
            if ca > 0.0:
                next_T = T * (1.0 - ca)
                if next_T <= T_MIN:
                    break
                w = ca * T
                T = next_T
                lab = labels[n]
                slot = int(-1)
                weakest = int(0)
                for s in range(buffer_size):
                    if labs[s] == lab:
                        slot = s
                    if ws[s] < ws[weakest]:
                        weakest = s
                if slot >= 0:
                    ws[slot] = ws[slot] + w
                elif filled < buffer_size:
                    labs[filled] = lab
                    ws[filled] = w
                    filled += 1
                else:
                    dropped += 1
                    if w > ws[weakest]:
                        labs[weakest] = lab
                        ws[weakest] = w
        best = int(-1)
        best_w = float(0.0)
        for s in range(buffer_size):
            if labs[s] >= 0 and ws[s] > best_w:
                best = labs[s]
                best_w = ws[s]
        buf_labels[out] = labs
        buf_weights[out] = ws
        out_labels[out] = best
        out_weights[out] = best_w
        overflows[out] = dropped

    @wp.kernel(enable_backward=False, module="unique")
    def semantic_contribution(
        means2d: wp.array(dtype=wp.vec2),
        conics: wp.array(dtype=wp.vec3),
        opacities: wp.array(dtype=float),
        labels: wp.array(dtype=wp.int32),
        confidences: wp.array(dtype=float),
        tile_start: wp.array(dtype=wp.int32),
        tile_end: wp.array(dtype=wp.int32),
        isect_ids: wp.array(dtype=wp.int32),
        buf_labels: wp.array(dtype=veci),
        buf_weights: wp.array(dtype=vecf),
        pixel_mask: wp.array(dtype=wp.uint8),
        use_mask: int,
        num_gaussians: int,
        width: int,
        height: int,
        tile_size: int,
        tiles_x: int,
        tiles_per_cam: int,
        numerator: wp.array(dtype=float),
        denominator: wp.array(dtype=float),
    ):
        """Accumulate sum_p w_ip R_p[l_i] and sum_p w_ip per Gaussian (dL_sq/ds_i and dL_lin/ds_i)."""
        pix = tile_pixel(wp.tid(), tile_size, tiles_x, tiles_per_cam, width, height)
        out = pix[0]
        if out < 0:
            return
        ct = pix[1]
        if use_mask != 0:
            if pixel_mask[out] == wp.uint8(0):
                return
        px = float(pix[2]) + 0.5
        py = float(pix[3]) + 0.5
        labs = buf_labels[out]
        ws = buf_weights[out]
        T = float(1.0)
        for i in range(tile_start[ct], tile_end[ct]):
            g = isect_ids[i]
            n = g % num_gaussians
            a = gaussian_alpha(conics[g], means2d[g], opacities[n], px, py)
            ca = confidences[n] * a[0]
            if ca > 0.0:
                next_T = T * (1.0 - ca)
                if next_T <= T_MIN:
                    break
                w = ca * T
                T = next_T
                lab = labels[n]
                r = float(0.0)
                for s in range(buffer_size):
                    if labs[s] == lab:
                        r = ws[s]
                wp.atomic_add(numerator, n, w * r)
                wp.atomic_add(denominator, n, w)

    return semantic_vote, semantic_contribution
