"""Value checks of the rendering inputs in one pass: a flag per failed check.

One launch replaces a couple of dozen small torch reductions (a finite test per tensor, the sign of the
scales, zero quaternions, the focal lengths), whose launch cost dominated a render's host time. Arrays
that a call does not have are passed empty. Threads that find a problem store 1 into its flag; every
writer stores the same value, so the race is harmless.
"""

import warp as wp

# flag index -> what failed, in the order the rasterizer reports them (its messages name the argument)
MEANS = wp.constant(0)
QUATS = wp.constant(1)
SCALES = wp.constant(2)
OPACITIES = wp.constant(3)
VIEWMATS = wp.constant(4)
KS = wp.constant(5)
SCALES_POSITIVE = wp.constant(6)
QUATS_NONZERO = wp.constant(7)
KS_FOCAL = wp.constant(8)
COLORS = wp.constant(9)
BACKGROUNDS = wp.constant(10)
CONFIDENCES = wp.constant(11)
CONFIDENCES_RANGE = wp.constant(12)
NUM_FLAGS = 13


@wp.kernel(enable_backward=False)
def check_inputs(
    means: wp.array(dtype=wp.vec3),
    quats: wp.array(dtype=wp.vec4),
    scales: wp.array(dtype=wp.vec3),
    opacities: wp.array(dtype=float),
    viewmats: wp.array(dtype=wp.mat44),
    Ks: wp.array(dtype=wp.mat33),
    colors: wp.array(dtype=float),
    backgrounds: wp.array(dtype=float),
    confidences: wp.array(dtype=float),
    flags: wp.array(dtype=wp.int32),
):
    i = wp.tid()
    if i < means.shape[0]:
        if not wp.isfinite(means[i]):
            flags[MEANS] = 1
        q = quats[i]
        if not wp.isfinite(q):
            flags[QUATS] = 1
        if q[0] == 0.0 and q[1] == 0.0 and q[2] == 0.0 and q[3] == 0.0:
            flags[QUATS_NONZERO] = 1
        s = scales[i]
        if not wp.isfinite(s):
            flags[SCALES] = 1
        if s[0] <= 0.0 or s[1] <= 0.0 or s[2] <= 0.0:
            flags[SCALES_POSITIVE] = 1
        if not wp.isfinite(opacities[i]):
            flags[OPACITIES] = 1
    if i < viewmats.shape[0]:
        if not wp.isfinite(viewmats[i]):
            flags[VIEWMATS] = 1
        K = Ks[i]
        if not wp.isfinite(K):
            flags[KS] = 1
        if K[0, 0] <= 0.0 or K[1, 1] <= 0.0:
            flags[KS_FOCAL] = 1
    if i < colors.shape[0]:
        if not wp.isfinite(colors[i]):
            flags[COLORS] = 1
    if i < backgrounds.shape[0]:
        if not wp.isfinite(backgrounds[i]):
            flags[BACKGROUNDS] = 1
    if i < confidences.shape[0]:
        c = confidences[i]
        if not wp.isfinite(c):
            flags[CONFIDENCES] = 1
        elif c < 0.0 or c > 1.0:
            flags[CONFIDENCES_RANGE] = 1
