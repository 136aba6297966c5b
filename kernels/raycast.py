"""Ray casting of a triangle mesh (``wp.Mesh`` BVH) into RGB, depth and instance images.

Used by the synthetic scene generator. One thread per (sub)pixel: the ray through the pixel
(x + s, y + s) (s = (k + 0.5) / sub, so sub = 1 is the pixel centre, the convention of K's cx, cy)
is cast from the camera centre; the hit gives depth (camera-space z in metres, 0 = no hit), the
instance id of the hit triangle and a Lambertian colour: per-triangle albedo modulated by a
procedural texture, lit by one point light with a hard shadow plus an ambient term. Shading depends
on the surface point only (never on the view direction), so the scene is view-consistent as a
Gaussian map assumes.

Texture codes (``tri_texture``): 0 plain, 1 checker (tiles), 2 stripes, 3 value noise (wood, foliage).
The texture coordinates are the hit point's two world coordinates orthogonal to the dominant axis of
the face normal, so axis-aligned planes get seamless patterns.
"""

import warp as wp

TEXTURE_PLAIN = 0
TEXTURE_CHECKER = 1
TEXTURE_STRIPES = 2
TEXTURE_NOISE = 3


@wp.func
def _plane_coords(p: wp.vec3, n: wp.vec3) -> wp.vec2:
    ax = wp.abs(n[0])
    ay = wp.abs(n[1])
    az = wp.abs(n[2])
    if ax >= ay and ax >= az:
        return wp.vec2(p[1], p[2])
    if ay >= az:
        return wp.vec2(p[0], p[2])
    return wp.vec2(p[0], p[1])


@wp.func
def _texture(code: int, scale: float, p: wp.vec3, n: wp.vec3) -> float:
    """Brightness factor in about [0.7, 1.1] for texture ``code`` at world point ``p``."""
    if code == 1:
        uv = _plane_coords(p, n) / scale
        parity = (int(wp.floor(uv[0])) + int(wp.floor(uv[1]))) % 2
        if parity != 0:
            return 0.8
        return 1.05
    if code == 2:
        uv = _plane_coords(p, n) / scale
        return 0.9 + 0.15 * wp.sin(6.2831853 * uv[0])
    if code == 3:
        state = wp.uint32(17)
        q = p / scale
        f = wp.noise(state, q) + 0.5 * wp.noise(state, q * 2.7)
        return 0.95 + 0.2 * f
    return 1.0


@wp.kernel(enable_backward=False)
def raycast_rgbd(
    mesh: wp.uint64,
    rot: wp.mat33,
    origin: wp.vec3,
    fx: float,
    fy: float,
    cx: float,
    cy: float,
    sub: int,
    max_depth: float,
    tri_color: wp.array(dtype=wp.vec3),
    tri_texture: wp.array(dtype=wp.int32),
    tri_texture_scale: wp.array(dtype=float),
    tri_instance: wp.array(dtype=wp.int32),
    light_pos: wp.vec3,
    light_range: float,
    ambient: float,
    shadows: int,
    rgb: wp.array2d(dtype=wp.vec3),
    depth: wp.array2d(dtype=float),
    instance: wp.array2d(dtype=wp.int32),
):
    """Grid [H * sub, W * sub]. ``rot``/``origin``: camera-to-world rotation and camera centre.

    rgb: linear colour in [0, 1]; depth: metres (0 = no hit); instance: id (0 = no hit).
    """
    i, j = wp.tid()
    u = (float(j) + 0.5) / float(sub)
    v = (float(i) + 0.5) / float(sub)
    # Camera-space direction with z = 1, so the ray parameter t of a hit *is* its depth.
    d = rot * wp.vec3((u - cx) / fx, (v - cy) / fy, 1.0)
    q = wp.mesh_query_ray(mesh, origin, d, max_depth)
    if not q.result:
        rgb[i, j] = wp.vec3(0.0, 0.0, 0.0)
        depth[i, j] = 0.0
        instance[i, j] = 0
        return
    f = q.face
    p = origin + q.t * d
    n = q.normal
    if wp.dot(n, d) > 0.0:
        n = -n
    to_light = light_pos - p
    dist = wp.length(to_light)
    l_dir = to_light / dist
    diffuse = wp.max(wp.dot(n, l_dir), 0.0)
    if shadows != 0 and diffuse > 0.0:
        start = p + n * 1.0e-3
        if wp.mesh_query_ray_anyhit(mesh, start, l_dir, dist - 2.0e-3):
            diffuse = 0.0
    falloff = 1.0 / (1.0 + (dist / light_range) * (dist / light_range))
    shade = ambient + (1.0 - ambient) * diffuse * falloff
    albedo = tri_color[f] * _texture(tri_texture[f], tri_texture_scale[f], p, n)
    c = albedo * shade
    rgb[i, j] = wp.vec3(wp.min(c[0], 1.0), wp.min(c[1], 1.0), wp.min(c[2], 1.0))
    depth[i, j] = q.t
    instance[i, j] = tri_instance[f]
