"""Confidence-weighted semantic voting (paper Eq. 3) and per-Gaussian rendering contribution (Eqs. 12-15).

Only labelled Gaussians are binned (the caller zeroes the others' screen radius), so unlabelled ones
neither vote nor occlude. Front to back, a Gaussian's effective opacity is conf * alpha:
    w_ip = conf_i * alpha_ip * prod_{j<i} (1 - conf_j * alpha_jp),   R_p[k] = sum_{i: l_i = k} w_ip.
Labels are unbounded ints, so each pixel keeps a bounded (label, weight) buffer in registers instead of
a K-vector: exact while a pixel sees at most ``buffer_size`` distinct labels. When a new label arrives
at a full buffer, the weakest entry (the new vote included) is dropped and the event is counted.
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
    lane_shfl,
    lane_shfl_int,
    lane_shfl_vec2,
    lane_shfl_vec3,
    lane_sum,
)
from .raster import (
    BLEND_BLOCK_DIM,
    BLEND_KERNEL_OPTIONS,
    T_MIN,
    gaussian_alpha,
    tile_pixel,
    warp_reaches,
    warp_rect,
)

VOTE_BLOCKS_PER_SM = 3


@wp.func
def load_lane_gaussian(
    j: int,
    end: int,
    isect_ids: wp.array(dtype=wp.int32),
    num_gaussians: int,
    means2d: wp.array(dtype=wp.vec2),
    conics: wp.array(dtype=wp.vec3),
    extents: wp.array(dtype=wp.vec2),
    opacities: wp.array(dtype=float),
    confidences: wp.array(dtype=float),
    labels: wp.array(dtype=wp.int32),
    rect: wp.vec4,
):
    """This lane's share of a batch: the j-th intersection's (Gaussian, mean2d, conic, opacity,
    confidence, label, whether it reaches the warp's ``rect``); past the tile's end a record that blends
    nothing and reaches no pixel."""
    if j < end:
        g = isect_ids[j]
        n = g % num_gaussians
        m = means2d[g]
        c = conics[g]
        o = opacities[n]
        if warp_reaches(m, c, o, extents[g], rect, lane_count()) != 0:
            return n, m, c, o, confidences[n], labels[n], int(1)
        return n, m, c, o, float(0.0), int(-1), int(0)  # never broadcast: its vote is not loaded
    return int(0), wp.vec2(), wp.vec3(), float(0.0), float(0.0), int(-1), int(0)


@wp.func
def lane_shfl_gaussian(gm: wp.vec2, gc: wp.vec3, go: float, gconf: float, glab: int, src: int):
    """Lane ``src``'s record from ``load_lane_gaussian``, broadcast to every lane of the warp."""
    return (
        lane_shfl_vec2(gm, src),
        lane_shfl_vec3(gc, src),
        lane_shfl(go, src),
        lane_shfl(gconf, src),
        lane_shfl_int(glab, src),
    )


@functools.cache
def semantic_kernels(buffer_size: int):
    """(vote, contribution) kernels for a per-pixel buffer of ``buffer_size`` entries."""
    veci = wp.types.vector(length=buffer_size, dtype=wp.int32)
    vecf = wp.types.vector(length=buffer_size, dtype=wp.float32)

    # Three 256-thread blocks per SM (<= 80 registers a thread), without spilling, measured 25-28% faster
    # on an H100 than the two blocks it got at 103 registers (benchmarks/kernel_resources.py prints them).
    @wp.kernel(**{**BLEND_KERNEL_OPTIONS, "launch_bounds": (BLEND_BLOCK_DIM, VOTE_BLOCKS_PER_SM)})
    def semantic_vote(
        means2d: wp.array(dtype=wp.vec2),
        conics: wp.array(dtype=wp.vec3),
        extents: wp.array(dtype=wp.vec2),
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
        tile_threads: int,
        tiles_x: int,
        tiles_per_cam: int,
        buf_labels: wp.array(dtype=veci),
        buf_weights: wp.array(dtype=vecf),
        out_labels: wp.array(dtype=wp.int32),
        out_weights: wp.array(dtype=float),
        overflows: wp.array(dtype=wp.int32),
    ):
        tid = wp.tid()
        pix = tile_pixel(tid, tile_size, tile_threads, tiles_x, tiles_per_cam, width, height)
        out = pix[0]
        ct = pix[1]
        px = float(pix[2]) + 0.5
        py = float(pix[3]) + 0.5
        W = lane_count()
        lane = tid % W
        rect = warp_rect(tid, tile_size, tile_threads, tiles_x, tiles_per_cam, W)
        end = tile_end[ct]
        T = float(1.0)
        labs = veci(-1)
        ws = vecf(0.0)
        filled = int(0)
        dropped = int(0)
        done = int(0)
        if out < 0:
            done = 1  # pixels past the image edge still take part in the lane shuffles
        b = tile_start[ct]
        while b < end:
            if lane_all(done) != 0:
                break
            gn, gm, gc, go, gconf, glab, reaches = load_lane_gaussian(
                b + lane, end, isect_ids, num_gaussians, means2d, conics, extents, opacities, confidences,
                labels, rect,
            )
            # only the batch's Gaussians that reach the warp's pixels are broadcast and evaluated
            pending = lane_ballot(reaches)
            while pending != 0:
                s = bit_lowest(pending)
                pending = bit_clear(pending, s)
                m, con, o, cf, lab = lane_shfl_gaussian(gm, gc, go, gconf, glab, s)
                if done == 0:
                    ca = cf * gaussian_alpha(con, m, o, px, py)[0]
                    if ca > 0.0:
                        next_T = T * (1.0 - ca)
                        if next_T <= T_MIN:
                            done = 1
                        else:
                            w = ca * T
                            T = next_T
                            # Constant-bound loops (unrolled) with predicated writes keep the buffer in
                            # registers; indexing it by a runtime slot would move it to local memory.
                            matched = int(0)
                            for k in range(buffer_size):
                                if labs[k] == lab:
                                    ws[k] = ws[k] + w
                                    matched = 1
                            if matched == 0:
                                if filled < buffer_size:
                                    for k in range(buffer_size):
                                        if k == filled:
                                            labs[k] = lab
                                            ws[k] = w
                                    filled += 1
                                else:
                                    # evict the weakest entry (the first of the lowest weight) if the vote
                                    # outweighs it; searching anew each time keeps fewer registers live than
                                    # tracking it, and registers bound this kernel's occupancy
                                    dropped += 1
                                    weakest = int(0)
                                    weakest_w = ws[0]
                                    for k in range(1, buffer_size):
                                        if ws[k] < weakest_w:
                                            weakest = k
                                            weakest_w = ws[k]
                                    if w > weakest_w:
                                        for k in range(buffer_size):
                                            if k == weakest:
                                                labs[k] = lab
                                                ws[k] = w
            b += W
        if out >= 0:
            best = int(-1)
            best_w = float(0.0)
            for k in range(buffer_size):
                if labs[k] >= 0 and ws[k] > best_w:
                    best = labs[k]
                    best_w = ws[k]
            buf_labels[out] = labs
            buf_weights[out] = ws
            out_labels[out] = best
            out_weights[out] = best_w
            overflows[out] = dropped

    @wp.kernel(**BLEND_KERNEL_OPTIONS)
    def semantic_contribution(
        means2d: wp.array(dtype=wp.vec2),
        conics: wp.array(dtype=wp.vec3),
        extents: wp.array(dtype=wp.vec2),
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
        tile_threads: int,
        tiles_x: int,
        tiles_per_cam: int,
        numerator: wp.array(dtype=float),
        denominator: wp.array(dtype=float),
    ):
        """Accumulate sum_p w_ip R_p[l_i] and sum_p w_ip per Gaussian (dL_sq/ds_i and dL_lin/ds_i)."""
        tid = wp.tid()
        pix = tile_pixel(tid, tile_size, tile_threads, tiles_x, tiles_per_cam, width, height)
        out = pix[0]
        ct = pix[1]
        px = float(pix[2]) + 0.5
        py = float(pix[3]) + 0.5
        W = lane_count()
        lane = tid % W
        rect = warp_rect(tid, tile_size, tile_threads, tiles_x, tiles_per_cam, W)
        end = tile_end[ct]
        labs = veci(-1)
        ws = vecf(0.0)
        done = int(0)
        if out < 0:
            done = 1
        else:
            if use_mask != 0:
                if pixel_mask[out] == wp.uint8(0):
                    done = 1
            labs = buf_labels[out]
            ws = buf_weights[out]
        T = float(1.0)
        b = tile_start[ct]
        while b < end:
            if lane_all(done) != 0:
                break
            gn, gm, gc, go, gconf, glab, reaches = load_lane_gaussian(
                b + lane, end, isect_ids, num_gaussians, means2d, conics, extents, opacities, confidences,
                labels, rect,
            )
            # only the batch's Gaussians that reach the warp's pixels are broadcast and evaluated
            pending = lane_ballot(reaches)
            while pending != 0:
                s = bit_lowest(pending)
                pending = bit_clear(pending, s)
                m, con, o, cf, lab = lane_shfl_gaussian(gm, gc, go, gconf, glab, s)
                hit = int(0)
                v_num = float(0.0)
                v_den = float(0.0)
                if done == 0:
                    ca = cf * gaussian_alpha(con, m, o, px, py)[0]
                    if ca > 0.0:
                        next_T = T * (1.0 - ca)
                        if next_T <= T_MIN:
                            done = 1
                        else:
                            w = ca * T
                            T = next_T
                            r = float(0.0)
                            for k in range(buffer_size):
                                if labs[k] == lab:
                                    r = ws[k]
                            hit = 1
                            v_num = w * r
                            v_den = w
                # one atomic per warp and Gaussian: sum the lanes' shares first
                if lane_any(hit) != 0:
                    n = lane_shfl_int(gn, s)
                    v_num = lane_sum(v_num)
                    v_den = lane_sum(v_den)
                    if lane == 0:
                        wp.atomic_add(numerator, n, v_num)
                        wp.atomic_add(denominator, n, v_den)
            b += W

    return semantic_vote, semantic_contribution
