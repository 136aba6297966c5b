"""Warp-lane (32-thread SIMT group) primitives for the per-pixel blending kernels.

On CUDA the blending kernels read Gaussians in batches of 32: each lane loads one Gaussian (parallel
loads, one memory latency per batch) and ``lane_shfl`` broadcasts it to the other lanes, as gsplat does
with shared memory. The backward sums each Gaussian's gradient across the lanes before one atomic add,
instead of one atomic per pixel. ``lane_ballot`` gives every lane the mask of lanes whose Gaussian
reaches the warp's pixels; the kernels visit only its set bits (``bit_lowest``, ``bit_clear``). On the
CPU device a "warp" is one thread: ``lane_count`` is 1, the shuffles and sums are the identity, the
ballot is the thread's own bit, and the same kernel source runs unchanged.

Every lane of a warp must reach each of these calls (the CUDA intrinsics use the full mask): call them
only under warp-uniform control flow. The kernels launch a multiple of 32 threads per block.
"""

import warp as wp


@wp.func_native(
    """
#if defined(__CUDA_ARCH__)
    return 32;
#else
    return 1;
#endif
"""
)
def lane_count() -> int: ...


@wp.func_native(
    """
#if defined(__CUDA_ARCH__)
    return __shfl_sync(0xffffffffu, x, src);
#else
    return x;
#endif
"""
)
def lane_shfl(x: float, src: int) -> float: ...


@wp.func_native(
    """
#if defined(__CUDA_ARCH__)
    return __shfl_sync(0xffffffffu, x, src);
#else
    return x;
#endif
"""
)
def lane_shfl_int(x: int, src: int) -> int: ...


@wp.func_native(
    """
#if defined(__CUDA_ARCH__)
    float v = x;
    for (int o = 16; o > 0; o >>= 1) v += __shfl_xor_sync(0xffffffffu, v, o);
    return v;
#else
    return x;
#endif
"""
)
def lane_sum(x: float) -> float: ...


@wp.func_native(
    """
#if defined(__CUDA_ARCH__) && __CUDA_ARCH__ >= 800
    return __reduce_add_sync(0xffffffffu, x);
#elif defined(__CUDA_ARCH__)
    int v = x;
    for (int o = 16; o > 0; o >>= 1) v += __shfl_xor_sync(0xffffffffu, v, o);
    return v;
#else
    return x;
#endif
"""
)
def lane_sum_int(x: int) -> int:
    """The sum of ``x`` over the warp's lanes, in every lane (one instruction from sm_80 on)."""
    ...


@wp.func_native(
    """
#if defined(__CUDA_ARCH__)
    int v = x;
    for (int o = 16; o > 0; o >>= 1) v = max(v, __shfl_xor_sync(0xffffffffu, v, o));
    return v;
#else
    return x;
#endif
"""
)
def lane_max_int(x: int) -> int: ...


@wp.func_native(
    """
#if defined(__CUDA_ARCH__)
    return __any_sync(0xffffffffu, p != 0) ? 1 : 0;
#else
    return p != 0 ? 1 : 0;
#endif
"""
)
def lane_any(p: int) -> int: ...


@wp.func_native(
    """
#if defined(__CUDA_ARCH__)
    return __all_sync(0xffffffffu, p != 0) ? 1 : 0;
#else
    return p != 0 ? 1 : 0;
#endif
"""
)
def lane_all(p: int) -> int: ...


@wp.func_native(
    """
#if defined(__CUDA_ARCH__)
    return (int)__ballot_sync(0xffffffffu, p != 0);
#else
    return p != 0 ? 1 : 0;
#endif
"""
)
def lane_ballot(p: int) -> int:
    """Bit k set where lane k's ``p`` is non-zero (the same mask in every lane)."""
    ...


@wp.func_native(
    """
#if defined(__CUDA_ARCH__)
    return __ffs(mask) - 1;
#else
    return mask == 0 ? -1 : __builtin_ctz((unsigned)mask);
#endif
"""
)
def bit_lowest(mask: int) -> int:
    """Index of the lowest set bit of a 32-bit mask, -1 if none."""
    ...


@wp.func_native(
    """
    return (int)((unsigned)mask & ~(1u << (unsigned)k));
"""
)
def bit_clear(mask: int, k: int) -> int:
    """``mask`` with bit ``k`` (0..31) cleared, without signed overflow at bit 31."""
    ...


@wp.func
def lane_shfl_vec2(v: wp.vec2, src: int) -> wp.vec2:
    return wp.vec2(lane_shfl(v[0], src), lane_shfl(v[1], src))


@wp.func
def lane_shfl_vec3(v: wp.vec3, src: int) -> wp.vec3:
    return wp.vec3(lane_shfl(v[0], src), lane_shfl(v[1], src), lane_shfl(v[2], src))
