"""Procedural indoor rooms as triangle meshes with instance ids, class names and relation triplets.

The builder works in a z-up frame (x, y horizontal, z up, floor at z = 0, room centred on the
origin) because furniture is easiest to reason about there; :func:`build_room` converts the result
into the ogscene3d world frame, in which **up is -y** (``WORLD_FROM_ZUP``), as ``gt/instances.json``
states (``"up"``), which ``graph.up_axis: auto`` reads: the synthetic scenes need no config override.

Placement is collision-free by construction: every object is a set of parts (boxes, cylinders,
frusta, ellipsoids), and a new object is accepted only if none of its parts' axis-aligned boxes
overlaps (beyond touching) a part of an object already placed. Objects rest on the top face of
their support (floor, table, cabinet, shelf board, sofa seat, another book), so "on"/"in"/
"attached to" relations are known exactly and recorded as ground truth.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

# z-up builder frame -> ogscene3d world (up = -y): (x, y, z) -> (x, -z, y); a proper rotation (det +1).
WORLD_FROM_ZUP = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])

TEXTURE_PLAIN, TEXTURE_CHECKER, TEXTURE_STRIPES, TEXTURE_NOISE = 0, 1, 2, 3

RELATION_VOCABULARY = ("on", "under", "above", "below", "next to", "in", "attached to")
INVERSE_RELATIONS = {"on": "under", "under": "on", "above": "below", "below": "above"}
STRUCTURAL_CLASSES = ("floor", "ceiling", "wall")
_EPS = 1e-4


# --------------------------------------------------------------------------------------- primitives


def yaw_matrix(yaw: float) -> np.ndarray:
    """The z-up builder frame's rotation by ``yaw`` radians about +z."""
    c, s = np.cos(yaw), np.sin(yaw)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def box_mesh(size: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Axis-aligned box of ``size`` (3,) centred on the origin: 8 vertices, 12 outward-wound triangles."""
    h = np.asarray(size, dtype=np.float64) / 2.0
    v = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)], dtype=np.float64) * h
    # vertex index = 4 * (x > 0) + 2 * (y > 0) + (z > 0)
    quads = [(0, 1, 3, 2), (4, 6, 7, 5), (0, 4, 5, 1), (2, 3, 7, 6), (0, 2, 6, 4), (1, 5, 7, 3)]
    tris = []
    for a, b, c, d in quads:
        tris += [(a, b, c), (a, c, d)]
    return v, np.array(tris, dtype=np.int64)


def frustum_mesh(
    r_bottom: float, r_top: float, height: float, segments: int = 16
) -> tuple[np.ndarray, np.ndarray]:
    """Closed cylinder/frustum along +z from z = 0 to ``height``."""
    a = np.linspace(0.0, 2.0 * np.pi, segments, endpoint=False)
    ring = np.stack([np.cos(a), np.sin(a)], axis=1)
    bottom = np.column_stack([ring * r_bottom, np.zeros(segments)])
    top = np.column_stack([ring * r_top, np.full(segments, height)])
    v = np.vstack([bottom, top, [[0.0, 0.0, 0.0], [0.0, 0.0, height]]])
    i = np.arange(segments)
    j = (i + 1) % segments
    cb, ct = 2 * segments, 2 * segments + 1
    side = np.concatenate([np.stack([i, j, j + segments], 1), np.stack([i, j + segments, i + segments], 1)])
    caps = np.concatenate(
        [
            np.stack([np.full(segments, cb), j, i], 1),
            np.stack([np.full(segments, ct), i + segments, j + segments], 1),
        ]
    )
    return v, np.concatenate([side, caps]).astype(np.int64)


def ellipsoid_mesh(radii: np.ndarray, rings: int = 8, segments: int = 14) -> tuple[np.ndarray, np.ndarray]:
    """UV ellipsoid centred on the origin."""
    theta = np.linspace(0.0, np.pi, rings + 1)[1:-1]
    phi = np.linspace(0.0, 2.0 * np.pi, segments, endpoint=False)
    t, p = np.meshgrid(theta, phi, indexing="ij")
    pts = np.stack([np.sin(t) * np.cos(p), np.sin(t) * np.sin(p), np.cos(t)], -1).reshape(-1, 3)
    v = np.vstack([[[0.0, 0.0, 1.0]], pts, [[0.0, 0.0, -1.0]]]) * np.asarray(radii, dtype=np.float64)
    n_r = rings - 1
    top, bot = 0, 1 + n_r * segments
    idx = lambda r, s: 1 + r * segments + (s % segments)  # noqa: E731
    tris = []
    for s in range(segments):
        tris.append((top, idx(0, s), idx(0, s + 1)))
        tris.append((bot, idx(n_r - 1, s + 1), idx(n_r - 1, s)))
        for r in range(n_r - 1):
            tris += [
                (idx(r, s), idx(r + 1, s), idx(r + 1, s + 1)),
                (idx(r, s), idx(r + 1, s + 1), idx(r, s + 1)),
            ]
    return v, np.array(tris, dtype=np.int64)


@dataclass
class Part:
    """One closed mesh piece of an object (z-up frame) with its albedo and texture."""

    vertices: np.ndarray  # float64 [V, 3]
    triangles: np.ndarray  # int64 [T, 3]
    color: np.ndarray  # float [3], linear RGB in [0, 1]
    texture: int = TEXTURE_PLAIN
    texture_scale: float = 0.25

    @property
    def aabb(self) -> tuple[np.ndarray, np.ndarray]:
        return self.vertices.min(0), self.vertices.max(0)


def make_part(
    kind: str,
    center: np.ndarray,
    color: np.ndarray,
    *,
    size: np.ndarray | None = None,
    radius: float = 0.0,
    radius_top: float | None = None,
    height: float = 0.0,
    radii: np.ndarray | None = None,
    rotation: np.ndarray | None = None,
    texture: int = TEXTURE_PLAIN,
    texture_scale: float = 0.25,
) -> Part:
    """A box (``center``: its centre), a frustum/cylinder (``center``: its base centre) or an ellipsoid."""
    if kind == "box":
        v, t = box_mesh(size)
    elif kind == "cylinder":
        v, t = frustum_mesh(radius, radius if radius_top is None else radius_top, height)
    elif kind == "ellipsoid":
        v, t = ellipsoid_mesh(radii)
    else:
        raise ValueError(f"unknown part kind {kind!r}")
    if rotation is not None:
        v = v @ np.asarray(rotation).T
    return Part(
        v + np.asarray(center, dtype=np.float64),
        t,
        np.asarray(color, dtype=np.float64),
        texture,
        texture_scale,
    )


@dataclass
class SceneObject:
    instance_id: int
    class_name: str
    parts: list[Part]
    support: int | None = None  # the instance this one rests on / is attached to
    support_relation: str | None = None  # "on" | "in" | "attached to"
    top_surfaces: list[tuple[np.ndarray, np.ndarray]] = field(default_factory=list)  # (xy min, xy max) at z

    @property
    def aabb(self) -> tuple[np.ndarray, np.ndarray]:
        lo = np.min([p.aabb[0] for p in self.parts], axis=0)
        hi = np.max([p.aabb[1] for p in self.parts], axis=0)
        return lo, hi


@dataclass
class Room:
    """A built room in the ogscene3d world frame (up = -y).

    ``vertices``/``triangles``: the whole scene mesh; ``tri_*``: per-triangle instance id, albedo,
    texture code and scale. ``objects``: per instance metadata; ``relations``: [subject, relation,
    object] triplets; ``size``: (width x, depth, height) in metres; ``light``: point light position.
    """

    vertices: np.ndarray
    triangles: np.ndarray
    tri_instance: np.ndarray
    tri_color: np.ndarray
    tri_texture: np.ndarray
    tri_texture_scale: np.ndarray
    objects: list[SceneObject]
    relations: list[tuple[int, str, int]]
    size: tuple[float, float, float]
    light: np.ndarray
    zup_objects: list[SceneObject]


def _overlaps(
    a: tuple[np.ndarray, np.ndarray], b: tuple[np.ndarray, np.ndarray], margin: float = 0.0
) -> bool:
    """Strict AABB overlap (touching is allowed) with ``margin`` of extra clearance in x and y only."""
    m = np.array([margin, margin, 0.0])
    return bool(np.all(a[0] < b[1] + m - _EPS) and np.all(b[0] < a[1] + m - _EPS))


# --------------------------------------------------------------------------------------- the builder


class SceneBuilder:
    """The objects of a room as they are placed (z-up builder frame), with the seeded ``rng`` that chooses
    sizes, colours and places; the builders of the room (:func:`build_room`), the apartment and the long
    scan share it and the part and placement helpers below, and :func:`finish_room` turns it into a
    :class:`Room`."""

    def __init__(self, rng: np.random.Generator):
        self.rng = rng
        self.objects: list[SceneObject] = []
        self.extra_relations: list[tuple[int, str, int]] = []

    def color(self, base: tuple[float, float, float], jitter: float = 0.06) -> np.ndarray:
        return np.clip(np.asarray(base) + self.rng.uniform(-jitter, jitter, 3), 0.02, 0.98)

    def vivid(self) -> np.ndarray:
        h = self.rng.uniform(0, 6)
        c = np.clip(np.abs(((h + np.array([0.0, 4.0, 2.0])) % 6.0) - 3.0) - 1.0, 0, 1)
        return 0.15 + 0.75 * c

    def collides(self, parts: list[Part], margin: float = 0.0, ignore: tuple[int, ...] = ()) -> bool:
        """Whether ``parts`` overlap a placed part. ``margin`` is extra horizontal clearance to
        non-structural objects; floor, walls and ceiling are only tested for strict overlap, so
        objects may stand on the floor and lean against walls."""
        for obj in self.objects:
            if obj.instance_id in ignore:
                continue
            m = 0.0 if obj.class_name in STRUCTURAL_CLASSES else margin
            for p in obj.parts:
                for q in parts:
                    if _overlaps(p.aabb, q.aabb, m):
                        return True
        return False

    def add(
        self,
        cls: str,
        parts: list[Part],
        support: int | None = None,
        relation: str | None = None,
        tops: list[tuple[np.ndarray, np.ndarray]] | None = None,
    ) -> SceneObject:
        obj = SceneObject(len(self.objects) + 1, cls, parts, support, relation, tops or [])
        self.objects.append(obj)
        return obj

    def try_add(
        self,
        cls: str,
        parts: list[Part],
        support: int | None = None,
        relation: str | None = None,
        tops: list | None = None,
        margin: float = 0.0,
        ignore: tuple[int, ...] = (),
    ) -> SceneObject | None:
        """Add the object unless it collides (see :meth:`collides`); None when it does."""
        if self.collides(parts, margin, ignore):
            return None
        return self.add(cls, parts, support, relation, tops)


def add_structure(b: SceneBuilder, W: float, D: float, H: float) -> dict[str, int]:
    """Floor, ceiling and four walls of a W x D x H room centred on the origin; their instance ids by name
    (``floor``, ``ceiling``, ``+x``, ``-x``, ``+y``, ``-y``)."""
    t = 0.05
    ids = add_floor_and_ceiling(b, W, D, H, t)
    wall_color = b.color((0.78, 0.76, 0.7), 0.1)
    walls = {
        "+x": ([W / 2 + t / 2, 0, H / 2], [t, D, H]),
        "-x": ([-W / 2 - t / 2, 0, H / 2], [t, D, H]),
        "+y": ([0, D / 2 + t / 2, H / 2], [W, t, H]),
        "-y": ([0, -D / 2 - t / 2, H / 2], [W, t, H]),
    }
    for name, (c, s) in walls.items():
        part = make_part(
            "box", c, wall_color * b.rng.uniform(0.93, 1.05), size=s, texture=TEXTURE_NOISE, texture_scale=0.6
        )
        ids[name] = b.add("wall", [part]).instance_id
    return ids


def add_floor_and_ceiling(b: SceneBuilder, W: float, D: float, H: float, t: float) -> dict[str, int]:
    """A W x D room's floor (top at z = 0) and ceiling (bottom at z = H), ``t`` thick, reaching under and
    over its walls; their instance ids by name."""
    ids = {}
    floor = make_part(
        "box",
        [0, 0, -t / 2],
        b.color((0.62, 0.5, 0.38)),
        size=[W + 2 * t, D + 2 * t, t],
        texture=TEXTURE_CHECKER,
        texture_scale=0.5,
    )
    ids["floor"] = b.add("floor", [floor]).instance_id
    ceiling = make_part(
        "box", [0, 0, H + t / 2], b.color((0.9, 0.9, 0.88), 0.03), size=[W + 2 * t, D + 2 * t, t]
    )
    ids["ceiling"] = b.add("ceiling", [ceiling]).instance_id
    return ids


def wall_frame(side: str, W: float, D: float) -> tuple[np.ndarray, np.ndarray, float, float]:
    """(point on wall at floor level, inward normal, half-length along the wall, yaw facing into the room)."""
    if side == "+x":
        return np.array([W / 2, 0, 0]), np.array([-1.0, 0, 0]), D / 2, np.pi
    if side == "-x":
        return np.array([-W / 2, 0, 0]), np.array([1.0, 0, 0]), D / 2, 0.0
    if side == "+y":
        return np.array([0, D / 2, 0]), np.array([0, -1.0, 0]), W / 2, -np.pi / 2
    return np.array([0, -D / 2, 0]), np.array([0, 1.0, 0]), W / 2, np.pi / 2


def against_wall(side: str, W: float, D: float, depth: float, along: float, z: float = 0.0):
    """Centre of a footprint ``depth`` deep touching wall ``side`` at offset ``along``; yaw into the room."""
    p, n, _, yaw = wall_frame(side, W, D)
    t = np.array([-n[1], n[0], 0.0])
    return p + n * depth / 2 + t * along + np.array([0, 0, z]), yaw


def rotated_size(size: np.ndarray, yaw: float) -> np.ndarray:
    """World AABB size of a box of local ``size`` turned by a multiple of 90 degrees."""
    quarter = int(round(yaw / (np.pi / 2))) % 2
    return np.array([size[1], size[0], size[2]]) if quarter else np.asarray(size, dtype=np.float64)


def local_point(center: np.ndarray, yaw: float, offset: Sequence[float] | np.ndarray) -> np.ndarray:
    """The point ``offset`` of a piece's own frame (turned by ``yaw`` about ``center``) in the builder
    frame."""
    return np.asarray(center) + yaw_matrix(yaw) @ np.asarray(offset, dtype=np.float64)


def table_parts(center: np.ndarray, yaw: float, size, color: np.ndarray) -> tuple[list[Part], list]:
    """A table standing at ``center`` (floor level), ``size`` = (length, width, height) in its own frame:
    its parts and its top surface (``SceneObject.top_surfaces``)."""
    L, Wd, Ht = size
    top_t = 0.04
    parts = [
        make_part(
            "box",
            center + [0, 0, Ht - top_t / 2],
            color,
            size=rotated_size([L, Wd, top_t], yaw),
            texture=TEXTURE_NOISE,
            texture_scale=0.15,
        )
    ]
    for sx in (-1, 1):
        for sy in (-1, 1):
            c = local_point(center, yaw, [sx * (L / 2 - 0.06), sy * (Wd / 2 - 0.06), (Ht - top_t) / 2])
            parts.append(make_part("box", c, color * 0.8, size=[0.05, 0.05, Ht - top_t]))
    half = rotated_size([L, Wd, 0], yaw)[:2] / 2
    top = (np.asarray(center)[:2] - half, np.asarray(center)[:2] + half, Ht)
    return parts, [top]


def chair_slots(lo: np.ndarray, hi: np.ndarray, gap) -> list[tuple[np.ndarray, float]]:
    """The four places (floor point, yaw) of a chair facing a table's sides (its box ``lo``, ``hi``), each
    ``gap()`` metres out (a draw per side, in this order)."""
    slots = []
    for axis in (0, 1):
        for sgn in (-1, 1):
            c = (lo + hi) / 2
            c[2] = 0.0
            c[axis] = (hi if sgn > 0 else lo)[axis] + sgn * gap()
            slots.append((c, np.arctan2(0, -sgn) if axis == 0 else np.arctan2(-sgn, 0)))
    return slots


def chair_parts(center: np.ndarray, yaw: float, color: np.ndarray) -> list[Part]:
    """A chair standing at ``center`` (floor level) and facing ``yaw``: seat, four legs and backrest."""
    s, seat_h, back_h = 0.44, 0.45, 0.45
    parts = [make_part("box", center + [0, 0, seat_h - 0.025], color, size=[s, s, 0.05])]
    for sx in (-1, 1):
        for sy in (-1, 1):
            c = local_point(center, yaw, [sx * (s / 2 - 0.03), sy * (s / 2 - 0.03), (seat_h - 0.05) / 2])
            parts.append(make_part("box", c, color * 0.75, size=[0.04, 0.04, seat_h - 0.05]))
    # backrest on the local -x side: the chair faces +x (its yaw)
    c = local_point(center, yaw, [-s / 2 + 0.02, 0, seat_h + back_h / 2])
    parts.append(make_part("box", c, color, size=rotated_size([0.04, s, back_h], yaw)))
    return parts


def shelf_parts(
    center: np.ndarray, yaw: float, size, color: np.ndarray, n_boards: int
) -> tuple[list[Part], list]:
    """An open bookshelf at ``center`` (floor level) with ``n_boards`` boards, ``size`` = (length, depth,
    height): its parts and the free space above each board (lo, hi, z, clearance) for books."""
    L, Dp, Ht = size
    t = 0.025
    parts = []
    for sx in (-1, 1):
        c = local_point(center, yaw, [0, sx * (L / 2 - t / 2), Ht / 2])
        parts.append(
            make_part(
                "box",
                c,
                color,
                size=rotated_size([Dp, t, Ht], yaw),
                texture=TEXTURE_NOISE,
                texture_scale=0.15,
            )
        )
    back = local_point(center, yaw, [-Dp / 2 + t / 2, 0, Ht / 2])
    parts.append(make_part("box", back, color * 0.85, size=rotated_size([t, L - 2 * t, Ht], yaw)))
    levels = np.linspace(0.0, Ht - t, n_boards + 1)
    tops = []
    for k, z in enumerate(levels):
        c = local_point(center, yaw, [t / 2, 0, z + t / 2])
        parts.append(
            make_part(
                "box",
                c,
                color,
                size=rotated_size([Dp - t, L - 2 * t, t], yaw),
                texture=TEXTURE_NOISE,
                texture_scale=0.15,
            )
        )
        if k < n_boards:
            inner = rotated_size([Dp - t, L - 2 * t, 0], yaw)[:2] / 2
            mid = local_point(center, yaw, [t / 2, 0, 0])[:2]
            tops.append((mid - inner, mid + inner, z + t, levels[k + 1] - (z + t)))
    return parts, tops


def cabinet_parts(center, yaw, size, col) -> tuple[list[Part], list]:
    """A closed cabinet of ``size`` (length along the wall, depth, height) with two door panels on its front
    (local +x), and its top surface."""
    body = make_part(
        "box", center + [0, 0, size[2] / 2], col, size=rotated_size([size[1], size[0], size[2]], yaw)
    )
    parts = [body]
    for k in range(2):
        fc = local_point(center, yaw, [size[1] / 2 + 0.005, 0, size[2] * (0.28 + 0.42 * k)])
        parts.append(
            make_part("box", fc, col * 0.9, size=rotated_size([0.01, size[0] * 0.9, size[2] * 0.38], yaw))
        )
    half = rotated_size([size[1], size[0], 0], yaw)[:2] / 2
    return parts, [(center[:2] - half, center[:2] + half, size[2])]


def sofa_parts(center, yaw, size, col) -> tuple[list[Part], list]:
    """A sofa of ``size`` (length, depth, height) facing local +x (seat, backrest, two arms) and its seat."""
    L, Dp, Hs = size
    seat_h, back_t, arm_w = 0.42, 0.2, 0.18
    parts = [
        make_part(
            "box",
            local_point(center, yaw, [back_t / 2, 0, seat_h / 2]),
            col,
            size=rotated_size([Dp - back_t, L - 2 * arm_w, seat_h], yaw),
            texture=TEXTURE_NOISE,
            texture_scale=0.08,
        ),
        make_part(
            "box",
            local_point(center, yaw, [-Dp / 2 + back_t / 2, 0, Hs / 2]),
            col * 0.9,
            size=rotated_size([back_t, L, Hs], yaw),
        ),
    ]
    for s in (-1, 1):
        parts.append(
            make_part(
                "box",
                local_point(center, yaw, [back_t / 2, s * (L / 2 - arm_w / 2), 0.3]),
                col * 0.95,
                size=rotated_size([Dp - back_t, arm_w, 0.6], yaw),
            )
        )
    seat_c = local_point(center, yaw, [back_t / 2, 0, 0])[:2]
    half = rotated_size([Dp - back_t - 0.1, L - 2 * arm_w - 0.05, 0], yaw)[:2] / 2
    return parts, [(seat_c - half, seat_c + half, seat_h)]


def decoration_parts(b: SceneBuilder, cls: str, side: str, W: float, D: float) -> list[Part] | None:
    """The parts of a wall decoration (door, window, picture or clock) at a random spot of wall ``side``,
    or None when the wall is too short for it."""
    rng = b.rng
    p, n, half_len, yaw = wall_frame(side, W, D)
    t_axis = np.array([-n[1], n[0], 0.0])
    if cls == "door":
        w, h, z0, thick, col = 0.9, 2.05, 0.0, 0.04, b.color((0.55, 0.4, 0.28))
    elif cls == "window":
        w, h, z0, thick, col = rng.uniform(0.9, 1.4), 1.0, 0.95, 0.03, b.color((0.6, 0.75, 0.9), 0.04)
    elif cls == "picture":
        w, h = rng.uniform(0.35, 0.7), rng.uniform(0.3, 0.5)
        z0, thick, col = rng.uniform(1.25, 1.65), 0.03, b.vivid()
    else:
        w = h = 0.3
        z0, thick, col = rng.uniform(1.6, 1.9), 0.04, b.color((0.92, 0.92, 0.9), 0.02)
    if half_len - w / 2 - 0.15 <= 0:
        return None
    along = rng.uniform(-half_len + w / 2 + 0.15, half_len - w / 2 - 0.15)
    c = p + n * thick / 2 + t_axis * along + [0, 0, z0 + h / 2]
    if cls == "clock":
        axis_rot = yaw_matrix(yaw) @ np.array([[0, 0, 1.0], [0, 1.0, 0], [-1.0, 0, 0]])
        return [make_part("cylinder", c - n * thick / 2, col, radius=w / 2, height=thick, rotation=axis_rot)]
    tex = TEXTURE_STRIPES if cls in ("picture", "window") else TEXTURE_PLAIN
    scale = float(rng.uniform(0.06, 0.2))
    return [make_part("box", c, col, size=rotated_size([thick, w, h], yaw), texture=tex, texture_scale=scale)]


def place_small(
    b: SceneBuilder, cls: str, support: SceneObject, top, relation: str = "on"
) -> SceneObject | None:
    """Try a few random spots on support surface ``top`` = (xy min, xy max, z[, clearance])."""
    lo, hi, z = top[0], top[1], top[2]
    clearance = top[3] if len(top) > 3 else 1.0
    rng = b.rng
    for _ in range(12):
        parts, footprint = small_object_parts(b, cls, clearance)
        if parts is None:
            return None
        room = (hi - lo) - footprint - 0.04
        if np.any(room <= 0):
            return None
        xy = lo + 0.02 + footprint / 2 + rng.uniform(0, 1, 2) * room
        moved = [
            Part(p.vertices + [xy[0], xy[1], z], p.triangles, p.color, p.texture, p.texture_scale)
            for p in parts
        ]
        obj = b.try_add(cls, moved, support.instance_id, relation, margin=0.02)
        if obj is not None:
            if cls == "book" and relation == "on":
                half = footprint / 2
                obj.top_surfaces.append((xy - half * 0.8, xy + half * 0.8, moved[0].aabb[1][2]))
            return obj
    return None


def small_object_parts(b: SceneBuilder, cls: str, clearance: float) -> tuple[list[Part] | None, np.ndarray]:
    """Parts of a small object, base centred at the origin (z = 0 on the support), and its xy footprint."""
    rng = b.rng
    c = b.vivid()
    if cls == "cup":
        r, h = rng.uniform(0.035, 0.05), rng.uniform(0.08, 0.12)
        parts = [make_part("cylinder", [0, 0, 0], c, radius=r, height=h)]
    elif cls == "bottle":
        r, h = rng.uniform(0.03, 0.045), rng.uniform(0.18, 0.26)
        parts = [
            make_part("cylinder", [0, 0, 0], c, radius=r, height=h * 0.7),
            make_part("cylinder", [0, 0, h * 0.7], c, radius=r, radius_top=r * 0.35, height=h * 0.3),
        ]
    elif cls == "bowl":
        r = rng.uniform(0.07, 0.1)
        parts = [make_part("ellipsoid", [0, 0, r * 0.35], c, radii=[r, r, r * 0.35])]
    elif cls == "ball":
        r = rng.uniform(0.05, 0.1)
        parts = [make_part("ellipsoid", [0, 0, r], c, radii=[r, r, r])]
    elif cls == "vase":
        r, h = rng.uniform(0.05, 0.07), rng.uniform(0.2, 0.3)
        parts = [
            make_part(
                "cylinder",
                [0, 0, 0],
                c,
                radius=r,
                radius_top=r * 0.6,
                height=h,
                texture=TEXTURE_STRIPES,
                texture_scale=0.05,
            )
        ]
    elif cls == "book":
        s = np.array([rng.uniform(0.15, 0.24), rng.uniform(0.2, 0.3), rng.uniform(0.025, 0.05)])
        parts = [make_part("box", [0, 0, s[2] / 2], c, size=s)]
    elif cls == "box":
        s = rng.uniform(0.12, 0.25, 3) * [1, 1, 0.8]
        parts = [make_part("box", [0, 0, s[2] / 2], b.color((0.6, 0.45, 0.3)), size=s)]
    elif cls == "laptop":
        w, d = 0.34, 0.24
        base = make_part("box", [0, 0, 0.01], b.color((0.25, 0.25, 0.28), 0.03), size=[w, d, 0.02])
        tilt = np.deg2rad(20.0)
        rot = np.array([[1, 0, 0], [0, np.cos(tilt), -np.sin(tilt)], [0, np.sin(tilt), np.cos(tilt)]])
        screen = make_part(
            "box",
            [0, -d / 2 + 0.006 - np.sin(tilt) * 0.11, 0.02 + np.cos(tilt) * 0.11],
            b.color((0.2, 0.22, 0.3), 0.03),
            size=[w, 0.012, 0.22],
            rotation=rot,
        )
        parts = [base, screen]
    elif cls == "lamp":
        shade = b.color((0.95, 0.9, 0.75), 0.04)
        parts = [
            make_part("cylinder", [0, 0, 0], b.color((0.3, 0.3, 0.3)), radius=0.08, height=0.03),
            make_part("cylinder", [0, 0, 0.03], b.color((0.3, 0.3, 0.3)), radius=0.012, height=0.3),
            make_part("cylinder", [0, 0, 0.25], shade, radius=0.14, radius_top=0.08, height=0.16),
        ]
    elif cls == "plant":
        r = rng.uniform(0.06, 0.09)
        parts = [
            make_part(
                "cylinder", [0, 0, 0], b.color((0.65, 0.35, 0.22)), radius=r, radius_top=r * 1.2, height=0.14
            ),
            make_part(
                "ellipsoid",
                [0, 0, 0.14 + 1.1 * r],
                b.color((0.2, 0.5, 0.2)),
                radii=[1.4 * r, 1.4 * r, 1.1 * r],
                texture=TEXTURE_NOISE,
                texture_scale=0.05,
            ),
        ]
    elif cls == "monitor":
        w, h = rng.uniform(0.45, 0.6), rng.uniform(0.28, 0.36)
        parts = _screen(b.color((0.08, 0.08, 0.1), 0.02), w, h, 0.04, [0.2, 0.15], [0.04, 0.03, 0.12])
    elif cls == "pillow":
        s = np.array([0.38, 0.14, 0.34])
        parts = [make_part("box", [0, 0, s[2] / 2], c, size=s, texture=TEXTURE_STRIPES, texture_scale=0.08)]
    elif cls == "tv":  # a flat screen on a foot (apartments' living rooms)
        w, h = rng.uniform(0.8, 1.1), rng.uniform(0.48, 0.62)
        parts = _screen(b.color((0.06, 0.06, 0.08), 0.02), w, h, 0.05, [0.3, 0.2], [0.05, 0.04, 0.1])
    elif cls == "sink":  # a basin with a tap on a counter or a vanity (apartments)
        steel = b.color((0.75, 0.77, 0.8), 0.04)
        parts = [
            make_part("box", [0, 0, 0.04], steel, size=[0.48, 0.38, 0.08]),
            make_part("box", [0, 0.15, 0.08 + 0.1], steel * 0.8, size=[0.03, 0.03, 0.2]),
        ]
    else:
        raise ValueError(f"unknown small object class {cls!r}")
    lo = np.min([p.aabb[0] for p in parts], 0)
    hi = np.max([p.aabb[1] for p in parts], 0)
    if hi[2] > clearance - 0.02:
        return None, np.zeros(2)
    if cls in ("book", "box", "laptop", "monitor", "pillow") and rng.uniform() < 0.5:
        rot = yaw_matrix(np.pi / 2)
        parts = [Part(p.vertices @ rot.T, p.triangles, p.color, p.texture, p.texture_scale) for p in parts]
        lo, hi = np.min([p.aabb[0] for p in parts], 0), np.max([p.aabb[1] for p in parts], 0)
    return parts, (hi - lo)[:2]


def _screen(color, w: float, h: float, thick: float, foot, stem) -> list[Part]:
    """A screen ``w`` x ``h`` (``thick`` deep) on a stem ``stem`` (x, y, height) over a 2 cm foot ``foot``
    (x, y), based at z = 0."""
    return [
        make_part("box", [0, 0, 0.01], color, size=[foot[0], foot[1], 0.02]),
        make_part("box", [0, 0, 0.02 + stem[2] / 2], color, size=stem),
        make_part("box", [0, 0, 0.02 + stem[2] + h / 2], color, size=[w, thick, h]),
    ]


def add_books_in_shelf(b: SceneBuilder, shelf: SceneObject, top) -> None:
    """A row of a few books standing "in" ``shelf`` on one of its boards (``top``: as :func:`shelf_parts`
    gives it)."""
    lo, hi, z, clearance = top
    rng = b.rng
    axis = int(np.argmax(hi - lo))  # books stand in a row along the long side of the board
    depth_len = (hi - lo)[1 - axis]
    pos = lo[axis] + rng.uniform(0.02, 0.2)
    remaining = int(rng.integers(3, 8))  # a few books per board, each still several pixels wide
    while remaining > 0:
        remaining -= 1
        thick = rng.uniform(0.03, 0.06)
        height = min(rng.uniform(0.18, 0.28), clearance - 0.03)
        deep = min(rng.uniform(0.14, 0.22), depth_len - 0.02)
        if pos + thick > hi[axis] - 0.02 or height < 0.1:
            return
        size = np.zeros(3)
        size[axis], size[1 - axis], size[2] = thick, deep, height
        c = np.zeros(3)
        c[axis] = pos + thick / 2
        c[1 - axis] = hi[1 - axis] - deep / 2 - 0.01
        c[2] = z + height / 2
        part = make_part("box", c, b.vivid() * rng.uniform(0.7, 1.0), size=size)
        b.try_add("book", [part], shelf.instance_id, "in", margin=0.002)
        gap = 0.004 if rng.uniform() < 0.7 else rng.uniform(0.08, 0.2)
        pos += thick + gap


def furniture_spot(b: SceneBuilder, sides: list[str], W: float, D: float, footprint: np.ndarray):
    """Random wall-adjacent placement of a footprint (length along wall, depth): (centre, yaw, side)."""
    side = sides[b.rng.integers(len(sides))]
    _, _, half_len, _ = wall_frame(side, W, D)
    span = half_len - footprint[0] / 2 - 0.1
    if span <= 0:
        return None
    along = b.rng.uniform(-span, span)
    center, yaw = against_wall(side, W, D, footprint[1], along)
    return center, yaw, side


def build_room(seed: int = 0) -> Room:
    """A deterministic random furnished room for ``seed`` (see module docstring for the frames)."""
    rng = np.random.default_rng(np.random.SeedSequence([seed, 0x5CE7E]))
    b = SceneBuilder(rng)
    W, D, H = rng.uniform(4.4, 5.4), rng.uniform(3.8, 4.6), rng.uniform(2.5, 2.8)
    ids = add_structure(b, W, D, H)
    floor = b.objects[ids["floor"] - 1]
    sides = ["+x", "-x", "+y", "-y"]

    wall_objs = _wall_furniture(b, sides, W, D, floor)
    table = _central_table(b, W, D, floor)
    if table is not None:
        _chairs(b, table, floor)
    _floor_items(b, sides, W, D, floor)
    _wall_decorations(b, sides, W, D, ids)
    light = _ceiling_lamp(b, ids, H, table)
    _small_objects(b, table, wall_objs)
    add_light_switches(b, ids, W, D, seed)
    add_floor_lamp(b, ids, W, D)

    return finish_room(b, (W, D, H), light)


def _wall_furniture(
    b: SceneBuilder, sides: list[str], W: float, D: float, floor: SceneObject
) -> list[SceneObject]:
    """Shelves, cabinets and a sofa against the walls, placed first."""
    rng = b.rng
    wall_items = ["bookshelf", "cabinet", "sofa"]
    if rng.uniform() < 0.6:
        wall_items.append("cabinet")
    wall_objs: list[SceneObject] = []
    for cls in wall_items:
        for _ in range(30):
            if cls == "bookshelf":
                size = np.array([rng.uniform(0.8, 1.2), 0.34, rng.uniform(1.5, 1.8)])
            elif cls == "cabinet":
                size = np.array([rng.uniform(0.8, 1.2), 0.45, rng.uniform(0.7, 0.85)])
            else:
                size = np.array([rng.uniform(1.6, 2.0), 0.85, 0.85])
            spot = furniture_spot(b, sides, W, D, size[:2])
            if spot is None:
                continue
            center, yaw, side = spot
            tops = []
            if cls == "bookshelf":
                parts, tops = shelf_parts(
                    center, yaw, size, b.color((0.55, 0.38, 0.22)), int(rng.integers(3, 5))
                )
            elif cls == "cabinet":
                parts, tops = cabinet_parts(center, yaw, size, b.color((0.85, 0.83, 0.78), 0.1))
            else:
                parts, tops = sofa_parts(center, yaw, size, b.color((0.35, 0.4, 0.55), 0.12))
            # Keep 0.9 m clear in front of wall furniture so the camera path never runs into it.
            obj = b.try_add(cls, parts, floor.instance_id, "on", tops, margin=0.15)
            if obj is not None:
                wall_objs.append(obj)
                break
    return wall_objs


def _central_table(b: SceneBuilder, W: float, D: float, floor: SceneObject) -> SceneObject | None:
    """The central table (None when it found no free spot)."""
    rng = b.rng
    table = None
    for _ in range(30):
        size = np.array([rng.uniform(1.0, 1.5), rng.uniform(0.7, 0.9), rng.uniform(0.72, 0.78)])
        yaw = float(rng.integers(2)) * np.pi / 2
        center = np.array(
            [rng.uniform(-0.3, 0.3) * (W / 2 - 1.4), rng.uniform(-0.3, 0.3) * (D / 2 - 1.4), 0.0]
        )
        parts, tops = table_parts(center, yaw, size, b.color((0.6, 0.42, 0.26)))
        table = b.try_add("table", parts, floor.instance_id, "on", tops, margin=0.6)
        if table is not None:
            break
    return table


def _chairs(b: SceneBuilder, table: SceneObject, floor: SceneObject) -> None:
    """Two to four chairs around the table."""
    rng = b.rng
    lo, hi = table.aabb
    chair_color = b.color((0.3, 0.22, 0.15), 0.08)
    slots = chair_slots(lo, hi, lambda: 0.22 + rng.uniform(0.05, 0.12))
    rng.shuffle(slots)
    for c, yaw in slots[: int(rng.integers(2, 5))]:
        b.try_add("chair", chair_parts(c, yaw, chair_color), floor.instance_id, "on", margin=0.05)


def _floor_items(b: SceneBuilder, sides: list[str], W: float, D: float, floor: SceneObject) -> None:
    """A plant and a trash can in free spots near the walls."""
    rng = b.rng
    for cls in ("plant", "trash can"):
        for _ in range(30):
            side = sides[rng.integers(4)]
            _, _, half_len, _ = wall_frame(side, W, D)
            center, _ = against_wall(side, W, D, 0.7, rng.uniform(-half_len + 0.4, half_len - 0.4))
            if cls == "plant":
                parts = [
                    make_part(
                        "cylinder", center, b.color((0.6, 0.3, 0.2)), radius=0.16, radius_top=0.2, height=0.4
                    ),
                    make_part(
                        "ellipsoid",
                        center + [0, 0, 0.75],
                        b.color((0.18, 0.45, 0.18)),
                        radii=[0.3, 0.3, 0.36],
                        texture=TEXTURE_NOISE,
                        texture_scale=0.08,
                    ),
                ]
            else:
                parts = [make_part("cylinder", center, b.color((0.5, 0.52, 0.55)), radius=0.14, height=0.32)]
            if b.try_add(cls, parts, floor.instance_id, "on", margin=0.1) is not None:
                break


def _wall_decorations(b: SceneBuilder, sides: list[str], W: float, D: float, ids: dict[str, int]) -> None:
    """A door, a window, pictures and a clock on the walls."""
    rng = b.rng
    for cls in ("door", "window", "picture", "picture", "picture", "clock"):
        for _ in range(30):
            side = sides[rng.integers(4)]
            parts = decoration_parts(b, cls, side, W, D)
            if parts is None:
                continue
            wall_id = ids[side]
            obj = b.try_add(cls, parts, wall_id, "attached to", margin=0.05)
            if obj is not None:
                if cls == "door":
                    b.extra_relations.append((obj.instance_id, "on", ids["floor"]))
                break


def _ceiling_lamp(b: SceneBuilder, ids: dict[str, int], H: float, table: SceneObject | None) -> np.ndarray:
    """A ceiling lamp above the table. -> where the scene's point light is (just below the lamp)."""
    light = np.array([0.0, 0.0, H - 0.45])
    if table is not None:
        lo, hi = table.aabb
        c = np.array([(lo[0] + hi[0]) / 2, (lo[1] + hi[1]) / 2, H])
        parts = [
            make_part("cylinder", c - [0, 0, 0.3], b.color((0.2, 0.2, 0.2)), radius=0.008, height=0.3),
            make_part(
                "cylinder",
                c - [0, 0, 0.42],
                b.color((0.95, 0.93, 0.85), 0.03),
                radius=0.22,
                radius_top=0.06,
                height=0.14,
            ),
        ]
        lamp = b.try_add("lamp", parts, ids["ceiling"], "attached to")
        if lamp is not None:
            b.extra_relations.append((lamp.instance_id, "above", table.instance_id))
            light = c - [0, 0, 0.5]
    return light


def _small_objects(b: SceneBuilder, table: SceneObject | None, wall_objs: list[SceneObject]) -> None:
    """Small objects on the top surfaces: the table, shelves, cabinets, sofa, then on some lying books."""
    rng = b.rng
    # Small objects on top surfaces.
    if table is not None:
        for cls in rng.choice(
            ["cup", "cup", "bottle", "bowl", "book", "laptop", "vase", "ball", "plant"],
            size=int(rng.integers(4, 7)),
            replace=False,
        ):
            place_small(b, str(cls), table, table.top_surfaces[0])
    for obj in wall_objs:
        if obj.class_name == "bookshelf":
            for k, top in enumerate(obj.top_surfaces):
                if k == 0 or rng.uniform() < 0.85:
                    add_books_in_shelf(b, obj, top)
                if rng.uniform() < 0.4:
                    place_small(b, str(rng.choice(["box", "vase", "plant"])), obj, top, "in")
        elif obj.class_name == "cabinet":
            for cls in rng.choice(
                ["lamp", "monitor", "plant", "book", "vase", "box"],
                size=int(rng.integers(1, 4)),
                replace=False,
            ):
                place_small(b, str(cls), obj, obj.top_surfaces[0])
        elif obj.class_name == "sofa":
            for _ in range(int(rng.integers(1, 3))):
                place_small(b, "pillow", obj, obj.top_surfaces[0])
    # A cup or a second book on some lying book: small objects resting on small objects.
    for obj in list(b.objects):
        if (
            obj.class_name == "book"
            and obj.support_relation == "on"
            and obj.top_surfaces
            and rng.uniform() < 0.7
        ):
            place_small(b, str(rng.choice(["cup", "book"])), obj, obj.top_surfaces[0])


def add_light_switches(b: SceneBuilder, ids: dict[str, int], W: float, D: float, seed: int) -> None:
    """One or two light switches on the walls: objects a few pixels wide from across the room, that SAM
    tends to absorb into the wall. Drawn from their own random stream, so that adding them moved no other
    object of a seed's room."""
    rng = np.random.default_rng(np.random.SeedSequence([seed, 0x5A17C]))
    sides = ["+x", "-x", "+y", "-y"]
    for _ in range(int(rng.integers(1, 3))):
        for _ in range(30):
            side = sides[rng.integers(4)]
            p, n, half_len, yaw = wall_frame(side, W, D)
            t_axis = np.array([-n[1], n[0], 0.0])
            w, h, thick = 0.09, 0.13, 0.015
            along = rng.uniform(-half_len + 0.3, half_len - 0.3)
            c = p + n * thick / 2 + t_axis * along + [0, 0, rng.uniform(1.05, 1.3)]
            part = make_part(
                "box", c, b.color((0.95, 0.95, 0.93), 0.02), size=rotated_size([thick, w, h], yaw)
            )
            if b.try_add("light switch", [part], ids[side], "attached to", margin=0.05) is not None:
                break


def add_floor_lamp(b: SceneBuilder, ids: dict[str, int], W: float, D: float) -> None:
    """A floor lamp by a wall when no lamp stands anywhere: the ceiling lamp is mostly above the camera, and
    a room's named objects should include a lamp one sees. Placed last, so that it moved no other object of
    a seed's room."""
    if any(o.class_name == "lamp" and o.support_relation == "on" for o in b.objects):
        return
    rng = b.rng
    sides = ["+x", "-x", "+y", "-y"]
    shade = b.color((0.95, 0.9, 0.75), 0.04)
    metal = b.color((0.25, 0.25, 0.25), 0.03)
    for _ in range(40):
        p, n, half_len, _ = wall_frame(sides[rng.integers(4)], W, D)
        t_axis = np.array([-n[1], n[0], 0.0])
        c = p + n * 0.3 + t_axis * rng.uniform(-half_len + 0.4, half_len - 0.4)
        parts = [
            make_part("cylinder", c, metal, radius=0.16, height=0.03),
            make_part("cylinder", c + [0, 0, 0.03], metal, radius=0.015, height=1.3),
            make_part("cylinder", c + [0, 0, 1.25], shade, radius=0.24, radius_top=0.15, height=0.32),
        ]
        if b.try_add("lamp", parts, ids["floor"], "on", margin=0.1) is not None:
            return


def _relations(b: SceneBuilder) -> list[tuple[int, str, int]]:
    rel: list[tuple[int, str, int]] = []
    for obj in b.objects:
        if obj.support is not None and obj.support_relation:
            rel.append((obj.instance_id, obj.support_relation, obj.support))
    rel += b.extra_relations
    # "next to": furniture pairs whose footprints are within 0.5 m, small objects on the same
    # support within 0.15 m. Symmetric, stored once with the smaller id as subject.
    objs = [
        o for o in b.objects if o.class_name not in STRUCTURAL_CLASSES and o.support_relation != "attached to"
    ]
    for i, a in enumerate(objs):
        for c in objs[i + 1 :]:
            if a.support != c.support or (a.support_relation, c.support_relation) != ("on", "on"):
                continue
            floor_level = b.objects[a.support - 1].class_name == "floor"
            gap_max = 0.5 if floor_level else 0.15
            la, ha = a.aabb
            lc, hc = c.aabb
            gap = np.maximum(np.maximum(la[:2] - hc[:2], lc[:2] - ha[:2]), 0.0)
            if np.linalg.norm(gap) < gap_max:
                rel.append((a.instance_id, "next to", c.instance_id))
    # A wall decoration above a piece of furniture it overlaps horizontally.
    for d in b.objects:
        if d.class_name not in ("picture", "clock", "window"):
            continue
        ld, hd = d.aabb
        for f in b.objects:
            if f.class_name in ("bookshelf", "cabinet", "sofa", "table", "plant", "trash can"):
                lf, hf = f.aabb
                if (
                    np.all(ld[:2] < hf[:2] + 0.05)
                    and np.all(lf[:2] < hd[:2] + 0.05)
                    and 0 < ld[2] - hf[2] < 1.0
                ):
                    rel.append((d.instance_id, "above", f.instance_id))
    assert all(r[1] in RELATION_VOCABULARY for r in rel)
    return rel


def finish_room(b: SceneBuilder, size: tuple[float, float, float], light_zup: np.ndarray) -> Room:
    """The built objects as a :class:`Room` in the ogscene3d world (up = -y): one mesh with per-triangle
    instance ids, colours and textures, and the relations; ``light_zup``: the point light (builder frame)."""
    verts, tris, inst, cols, tex, tex_s = [], [], [], [], [], []
    offset = 0
    zup_objects = b.objects
    world_objects = []
    for obj in b.objects:
        world_parts = []
        for p in obj.parts:
            wv = p.vertices @ WORLD_FROM_ZUP.T
            world_parts.append(Part(wv, p.triangles, p.color, p.texture, p.texture_scale))
            verts.append(wv)
            tris.append(p.triangles + offset)
            offset += len(p.vertices)
            n = len(p.triangles)
            inst.append(np.full(n, obj.instance_id, dtype=np.int32))
            cols.append(np.repeat(p.color[None], n, 0))
            tex.append(np.full(n, p.texture, dtype=np.int32))
            tex_s.append(np.full(n, p.texture_scale, dtype=np.float32))
        world_objects.append(
            SceneObject(obj.instance_id, obj.class_name, world_parts, obj.support, obj.support_relation)
        )
    return Room(
        vertices=np.concatenate(verts).astype(np.float32),
        triangles=np.concatenate(tris).astype(np.int32),
        tri_instance=np.concatenate(inst),
        tri_color=np.concatenate(cols).astype(np.float32),
        tri_texture=np.concatenate(tex),
        tri_texture_scale=np.concatenate(tex_s),
        objects=world_objects,
        relations=_relations(b),
        size=size,
        light=(WORLD_FROM_ZUP @ light_zup).astype(np.float32),
        zup_objects=zup_objects,
    )
