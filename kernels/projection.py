"""EWA projection of 3D Gaussians into each camera (gsplat's math, no antialiasing compensation).

The kernel is straight-line code, so its backward is Warp's generated adjoint (launched with
``adjoint=True``); only the blending loops need hand-written backward kernels.
"""

import warp as wp

mat23 = wp.types.matrix(shape=(2, 3), dtype=wp.float32)

# gsplat's ALPHA_THRESHOLD: the screen radius reaches where alpha falls below it
ALPHA_THRESHOLD = wp.constant(1.0 / 255.0)


@wp.func
def quat_wxyz_to_mat(q: wp.vec4) -> wp.mat33:
    n = wp.normalize(q)
    w = n[0]
    x = n[1]
    y = n[2]
    z = n[3]
    return wp.mat33(
        1.0 - 2.0 * (y * y + z * z),
        2.0 * (x * y - w * z),
        2.0 * (x * z + w * y),
        2.0 * (x * y + w * z),
        1.0 - 2.0 * (x * x + z * z),
        2.0 * (y * z - w * x),
        2.0 * (x * z - w * y),
        2.0 * (y * z + w * x),
        1.0 - 2.0 * (x * x + y * y),
    )


@wp.func
def cull(
    tid: int,
    means2d: wp.array(dtype=wp.vec2),
    conics: wp.array(dtype=wp.vec3),
    depths: wp.array(dtype=float),
    radii: wp.array(dtype=wp.int32),
):
    """A culled entry: radius 0 and zeros, so the outputs need no clearing before the launch."""
    radii[tid] = 0
    means2d[tid] = wp.vec2(0.0, 0.0)
    conics[tid] = wp.vec3(0.0, 0.0, 0.0)
    depths[tid] = 0.0


@wp.kernel
def project_gaussians(
    means: wp.array(dtype=wp.vec3),
    quats: wp.array(dtype=wp.vec4),
    scales: wp.array(dtype=wp.vec3),
    opacities: wp.array(dtype=float),
    viewmats: wp.array(dtype=wp.mat44),
    Ks: wp.array(dtype=wp.mat33),
    num_gaussians: int,
    width: int,
    height: int,
    near_plane: float,
    far_plane: float,
    eps2d: float,
    means2d: wp.array(dtype=wp.vec2),
    conics: wp.array(dtype=wp.vec3),
    depths: wp.array(dtype=float),
    radii: wp.array(dtype=wp.int32),
):
    """One thread per (camera, Gaussian); outputs are flattened as c * N + n. radius 0 means culled.

    The screen radius is gsplat's (1.5): per axis ceil(e * sqrt(cov2d_ii)), e = min(3.33,
    sqrt(2 ln(255 o))), the bounding box of the alpha >= 1/255 ellipse; opacity < 1/255 is culled, and the
    box decides the outside-the-image culling. ``radii`` holds the larger of the two."""
    tid = wp.tid()
    c = tid // num_gaussians
    n = tid - c * num_gaussians
    V = viewmats[c]
    K = Ks[c]
    R = wp.mat33(V[0, 0], V[0, 1], V[0, 2], V[1, 0], V[1, 1], V[1, 2], V[2, 0], V[2, 1], V[2, 2])
    t = wp.vec3(V[0, 3], V[1, 3], V[2, 3])
    p = R * means[n] + t
    z = p[2]
    if z <= near_plane or z >= far_plane:
        cull(tid, means2d, conics, depths, radii)
        return

    M = quat_wxyz_to_mat(quats[n])
    s = scales[n]
    RS = M * wp.diag(s)
    cov_w = RS * wp.transpose(RS)
    cov_c = R * cov_w * wp.transpose(R)

    fx = K[0, 0]
    fy = K[1, 1]
    cx = K[0, 2]
    cy = K[1, 2]
    # Clamp the Jacobian's evaluation point to 1.3x the field of view, as 3DGS/gsplat do, so that
    # Gaussians far outside the image do not get exploding screen-space covariances.
    tan_fovx = 0.5 * float(width) / fx
    tan_fovy = 0.5 * float(height) / fy
    lim_x_pos = (float(width) - cx) / fx + 0.3 * tan_fovx
    lim_x_neg = cx / fx + 0.3 * tan_fovx
    lim_y_pos = (float(height) - cy) / fy + 0.3 * tan_fovy
    lim_y_neg = cy / fy + 0.3 * tan_fovy
    rz = 1.0 / z
    tx = z * wp.min(lim_x_pos, wp.max(-lim_x_neg, p[0] * rz))
    ty = z * wp.min(lim_y_pos, wp.max(-lim_y_neg, p[1] * rz))
    J = mat23(fx * rz, 0.0, -fx * tx * rz * rz, 0.0, fy * rz, -fy * ty * rz * rz)
    cov2d = J * cov_c * wp.transpose(J)
    a = cov2d[0, 0] + eps2d
    b = cov2d[0, 1]
    d = cov2d[1, 1] + eps2d
    det = a * d - b * b
    # not finite: a Gaussian so large (kilometres at arm's length) that float32 overflows; it is dropped
    if det <= 0.0 or not wp.isfinite(det):
        cull(tid, means2d, conics, depths, radii)
        return
    inv_det = 1.0 / det
    mean2d = wp.vec2(fx * p[0] * rz + cx, fy * p[1] * rz + cy)

    # radii bounded so that the int32 radius cannot wrap around; far beyond any image either way
    o = opacities[n]
    if not (o >= ALPHA_THRESHOLD):
        cull(tid, means2d, conics, depths, radii)
        return
    extend = wp.min(3.33, wp.sqrt(2.0 * wp.log(o / ALPHA_THRESHOLD)))
    rx = wp.min(wp.ceil(extend * wp.sqrt(a)), 1.0e8)
    ry = wp.min(wp.ceil(extend * wp.sqrt(d)), 1.0e8)
    if (
        (rx <= 0.0 and ry <= 0.0)
        or mean2d[0] + rx <= 0.0
        or mean2d[0] - rx >= float(width)
        or mean2d[1] + ry <= 0.0
        or mean2d[1] - ry >= float(height)
    ):
        cull(tid, means2d, conics, depths, radii)
        return

    radii[tid] = wp.int32(wp.max(rx, ry))
    means2d[tid] = mean2d
    conics[tid] = wp.vec3(d * inv_det, -b * inv_det, a * inv_det)
    depths[tid] = z
