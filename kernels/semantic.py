"""Confidence-weighted semantic voting (paper Eq. 3) and per-Gaussian rendering contribution (Eqs. 12-15).

Only labelled Gaussians of confidence > 0 are binned (``bin_gaussians(..., voters=...)`` leaves the others
out), so unlabelled ones neither vote nor occlude. Front to back, a Gaussian's effective opacity is
conf * alpha:
    w_ip = conf_i * alpha_ip * prod_{j<i} (1 - conf_j * alpha_jp),   R_p[k] = sum_{i: l_i = k} w_ip.
Labels are unbounded ints, so each pixel keeps a bounded (label, weight) buffer in registers instead of
a K-vector: exact while a pixel sees at most ``buffer_size`` distinct labels. Consecutive votes of one
label (a run) are summed before they enter the buffer. When a new label's run arrives at a full buffer,
the weakest entry (the run included) is dropped and the event is counted.

P_conf(i) = sum_p w_ip R_p[l_i] / sum_p w_ip needs each pixel's final R_p, so the Gaussians are walked
twice. One kernel makes both walks, tile by tile: the second reads the buffer from the first's registers
and finds the tile's Gaussians likely still in the SM's L1 cache.
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
    lane_sum_int,
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
def semantic_kernel(buffer_size: int):
    """The voting (and, with ``contribute``, rendering contribution) kernel for a per-pixel buffer of
    ``buffer_size`` entries."""
    veci = wp.types.vector(length=buffer_size, dtype=wp.int32)
    vecf = wp.types.vector(length=buffer_size, dtype=wp.float32)

    # Three 256-thread blocks per SM (<= 80 registers a thread), without spilling, measured 25-28% faster
    # on an H100 than the two blocks it got at 103 registers (benchmarks/kernel_resources.py prints them).
    @wp.kernel(**{**BLEND_KERNEL_OPTIONS, "launch_bounds": (BLEND_BLOCK_DIM, VOTE_BLOCKS_PER_SM)})
    def semantic_render(
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
        write_buffer: int,
        contribute: int,
        pixel_mask: wp.array(dtype=wp.uint8),
        use_mask: int,
        buf_labels: wp.array(dtype=veci),
        buf_weights: wp.array(dtype=vecf),
        out_labels: wp.array(dtype=wp.int32),
        out_weights: wp.array(dtype=float),
        overflow_counts: wp.array(dtype=wp.int64),
        numerator: wp.array(dtype=float),
        denominator: wp.array(dtype=float),
    ):
        """Per pixel the label and its weight (and with ``write_buffer`` the buffer); added to
        ``overflow_counts`` the pixels whose buffer overflowed and the runs that met a full buffer; with
        ``contribute``, per Gaussian sum_p w_ip R_p[l_i] and sum_p w_ip (dL_sq/ds_i and dL_lin/ds_i) over
        the pixels of ``pixel_mask`` (all unless ``use_mask``)."""
        tid = wp.tid()
        pix = tile_pixel(tid, tile_size, tile_threads, tiles_x, tiles_per_cam, width, height)
        out = pix[0]
        ct = pix[1]
        px = float(pix[2]) + 0.5
        py = float(pix[3]) + 0.5
        W = lane_count()
        lane = tid % W
        rect = warp_rect(tid, tile_size, tile_threads, tiles_x, tiles_per_cam, W)
        start = tile_start[ct]
        end = tile_end[ct]
        T = float(1.0)
        labs = veci(-1)
        ws = vecf(0.0)
        filled = int(0)
        dropped = int(0)
        # the current run: consecutive votes of one label (a surface's layers) are summed first and enter
        # the buffer as one, so a warp updates it for about a quarter of the Gaussians it blends on a
        # mapped scene instead of for each
        run_lab = int(-1)
        run_w = float(0.0)
        done = int(0)
        if out < 0:
            done = 1  # pixels past the image edge still take part in the lane shuffles
        b = start
        last_round = int(0)
        while last_round == 0:
            batch_end = end
            pending = int(1)  # the last round loads nothing and visits one bit, to flush every lane's run
            if b >= end or lane_all(done) != 0:
                last_round = 1
                batch_end = b
            gn, gm, gc, go, gconf, glab, reaches = load_lane_gaussian(
                b + lane, batch_end, isect_ids, num_gaussians, means2d, conics, extents, opacities,
                confidences, labels, rect,
            )
            if last_round == 0:
                # only the batch's Gaussians that reach the warp's pixels are broadcast and evaluated
                pending = lane_ballot(reaches)
            while pending != 0:
                s = bit_lowest(pending)
                pending = bit_clear(pending, s)
                m, con, o, cf, lab = lane_shfl_gaussian(gm, gc, go, gconf, glab, s)
                w = float(0.0)
                new_run = last_round
                if done == 0 and last_round == 0:
                    ca = cf * gaussian_alpha(con, m, o, px, py)[0]
                    if ca > 0.0:
                        next_T = T * (1.0 - ca)
                        if next_T <= T_MIN:
                            done = 1
                        else:
                            w = ca * T
                            T = next_T
                            if lab != run_lab:
                                new_run = 1
                            else:
                                run_w += w
                # The buffer update, written once for both the runs a new label ends and the last round's.
                # Constant-bound loops (unrolled) with predicated writes keep the buffer in registers;
                # indexing it by a runtime slot would move it to local memory.
                if new_run != 0 and run_lab >= 0:
                    matched = int(0)
                    for k in range(buffer_size):
                        if labs[k] == run_lab:
                            ws[k] = ws[k] + run_w
                            matched = 1
                    if matched == 0:
                        if filled < buffer_size:
                            for k in range(buffer_size):
                                if k == filled:
                                    labs[k] = run_lab
                                    ws[k] = run_w
                            filled += 1
                        else:
                            # evict the weakest entry (the first of the lowest weight) if the run outweighs
                            # it; searching anew each time keeps fewer registers live than tracking it, and
                            # registers bound this kernel's occupancy
                            dropped += 1
                            weakest = int(0)
                            weakest_w = ws[0]
                            for k in range(1, buffer_size):
                                if ws[k] < weakest_w:
                                    weakest = k
                                    weakest_w = ws[k]
                            if run_w > weakest_w:
                                for k in range(buffer_size):
                                    if k == weakest:
                                        labs[k] = run_lab
                                        ws[k] = run_w
                if new_run != 0:
                    run_lab = lab
                    run_w = w
            b += W
        if out >= 0:
            best = int(-1)
            best_w = float(0.0)
            for k in range(buffer_size):
                if labs[k] >= 0 and ws[k] > best_w:
                    best = labs[k]
                    best_w = ws[k]
            if write_buffer != 0:
                buf_labels[out] = labs
                buf_weights[out] = ws
            out_labels[out] = best
            out_weights[out] = best_w
        # the totals are all the caller reads of the overflows: one atomic per warp that had any
        overflowed = int(0)
        if dropped > 0:
            overflowed = 1
        over_pixels = lane_sum_int(overflowed)
        over_runs = lane_sum_int(dropped)
        if lane == 0 and over_runs > 0:
            wp.atomic_add(overflow_counts, 0, wp.int64(over_pixels))
            wp.atomic_add(overflow_counts, 1, wp.int64(over_runs))
        if contribute == 0:
            return
        # The second walk: the same weights w_ip again, now with the pixel's final R_p at hand.
        T = float(1.0)
        r_lab = int(-1)
        r = float(0.0)
        done = int(0)
        if out < 0:
            done = 1
        elif use_mask != 0:
            if pixel_mask[out] == wp.uint8(0):
                done = 1
        b = start
        while b < end:
            if lane_all(done) != 0:
                break
            gn, gm, gc, go, gconf, glab, reaches = load_lane_gaussian(
                b + lane, end, isect_ids, num_gaussians, means2d, conics, extents, opacities, confidences,
                labels, rect,
            )
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
                            # R_p of the last label looked up serves its runs
                            if lab != r_lab:
                                r_lab = lab
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

    return semantic_render
