"""Procedural apartments: 2-5 furnished rooms joined by doorways, with the room of every surface and a camera
path that walks from room to room.

The builder works in the z-up frame of :mod:`.procedural` and reuses its parts and placement (furniture
against walls, small objects on top surfaces, books in shelves, wall decorations); ``finish_room`` converts
the result into the ogscene3d world (up = -y). Rooms lie in a row along x, aligned on their -y walls; every
room is a box with its own floor, ceiling and four walls (neighbours' walls stand back to back, 2 x 5 cm), and
each pair of neighbours shares a doorway :data:`DOOR_WIDTH` wide and :data:`DOOR_HEIGHT` high cut through
both walls. A room's type (:data:`ROOM_TYPES`) chooses its furniture: a bed with pillows and nightstands in
a bedroom, a counter with a sink, a refrigerator, a stove and a table with chairs in a kitchen, and so on.

Every instance belongs to exactly one room (its walls and floor included), so each surface point's room is
known. The camera (:func:`apartment_camera`) starts in the first room, turns once around at the most
open spot of each room, and walks through the doorways to the next room along paths that keep clear of the
furniture.
"""

from __future__ import annotations

import heapq
from dataclasses import dataclass, field, fields

import numpy as np

from .procedural import (
    STRUCTURAL_CLASSES,
    TEXTURE_NOISE,
    WORLD_FROM_ZUP,
    Part,
    Room,
    SceneBuilder,
    SceneObject,
    add_books_in_shelf,
    add_floor_and_ceiling,
    add_floor_lamp,
    add_light_switches,
    against_wall,
    cabinet_parts,
    chair_parts,
    decoration_parts,
    finish_room,
    furniture_spot,
    local_point,
    make_part,
    place_small,
    rotated_size,
    shelf_parts,
    small_object_parts,
    sofa_parts,
    table_parts,
    wall_frame,
    yaw_matrix,
)

#: The room types of an apartment, each with its typical furniture.
ROOM_TYPES: tuple[str, ...] = ("living room", "kitchen", "bedroom", "bathroom", "office")
#: Interior size ranges (metres) per room type: (width along the row, depth).
ROOM_SIZES: dict[str, tuple[tuple[float, float], tuple[float, float]]] = {
    "living room": ((4.4, 5.2), (4.2, 5.0)),
    "kitchen": ((3.6, 4.2), (3.6, 4.4)),
    "bedroom": ((4.0, 4.6), (4.0, 4.6)),
    "bathroom": ((2.8, 3.2), (2.8, 3.2)),
    "office": ((3.6, 4.2), (3.6, 4.2)),
}
WALL_THICKNESS = 0.05  # each room's own wall; neighbours' walls stand back to back
DOOR_WIDTH = 0.9
DOOR_HEIGHT = 2.05
_SIDES = ["+x", "-x", "+y", "-y"]
_KEEPOUT = "keepout"  # placeholder objects that keep furniture out of doorways; never part of the scene
_CLEARANCE = 0.4  # metres the camera path keeps from furniture and walls inside a room
_GRID = 0.05  # metres per cell of the path planner's grid


@dataclass
class ApartmentRoom:
    """One room of an apartment: ``id`` from 1, its ``type``, storey ``floor`` (0: one-storey apartments) and
    its interior (floor to ceiling, inside the walls) as a box in the world frame (metres)."""

    id: int
    type: str
    floor: int
    bbox_min: np.ndarray
    bbox_max: np.ndarray
    zup_min: np.ndarray  # interior rectangle (x, y) in the builder's z-up frame
    zup_max: np.ndarray


@dataclass
class Apartment(Room):
    """A :class:`~ogscene3d.datasets.procedural.Room` (the whole apartment's mesh and objects) with its rooms:
    ``rooms`` in the order the camera visits them, ``instance_room`` {instance id: room id} for every
    instance, ``doors`` [(room a, room b, doorway centre (x, y) in the z-up frame)]."""

    rooms: list[ApartmentRoom] = field(default_factory=list)
    instance_room: dict[int, int] = field(default_factory=dict)
    doors: list[tuple[int, int, np.ndarray]] = field(default_factory=list)


# --------------------------------------------------------------------------------------- one room


def _wall_parts(side: str, W: float, D: float, H: float, color, openings: list[float]):
    """Wall ``side`` of a W x D x H room as boxes around doorways centred at ``openings`` (offsets along the
    wall's own axis, x for the +-y walls, y for the +-x walls)."""
    t = WALL_THICKNESS
    along_x = side in ("+y", "-y")
    length = W if along_x else D
    fixed = {"+x": W / 2 + t / 2, "-x": -W / 2 - t / 2, "+y": D / 2 + t / 2, "-y": -D / 2 - t / 2}[side]

    def box(a0: float, a1: float, z0: float, z1: float) -> Part:
        mid, extent = (a0 + a1) / 2, a1 - a0
        c = [mid, fixed, (z0 + z1) / 2] if along_x else [fixed, mid, (z0 + z1) / 2]
        s = [extent, t, z1 - z0] if along_x else [t, extent, z1 - z0]
        return make_part("box", c, color, size=s, texture=TEXTURE_NOISE, texture_scale=0.6)

    parts, start = [], -length / 2
    for o in sorted(openings):
        lo, hi = o - DOOR_WIDTH / 2, o + DOOR_WIDTH / 2
        if lo - start > 1e-6:
            parts.append(box(start, lo, 0.0, H))
        parts.append(box(lo, hi, DOOR_HEIGHT, H))  # the lintel
        start = hi
    if length / 2 - start > 1e-6:
        parts.append(box(start, length / 2, 0.0, H))
    return parts


def _room_shell(
    b: SceneBuilder, W: float, D: float, H: float, doors: dict[str, list[float]]
) -> dict[str, int]:
    """Floor, ceiling and four walls (with doorways at ``doors`` {side: offsets}) of a room centred on the
    origin, and a keep-out box in front of every doorway; the instance ids by name as ``add_structure``'s."""
    ids = add_floor_and_ceiling(b, W, D, H, WALL_THICKNESS)
    wall_color = b.color((0.78, 0.76, 0.7), 0.1)
    for side in _SIDES:
        color = wall_color * b.rng.uniform(0.93, 1.05)
        ids[side] = b.add("wall", _wall_parts(side, W, D, H, color, doors.get(side, []))).instance_id
    for side, offsets in doors.items():
        p, n, _, _ = wall_frame(side, W, D)
        for o in offsets:
            along = np.array([1.0, 0, 0]) if side in ("+y", "-y") else np.array([0, 1.0, 0])
            c = p + n * 0.65 + along * o + [0, 0, (DOOR_HEIGHT + 0.05) / 2]
            size = np.abs(n) * 1.3 + along * (DOOR_WIDTH + 0.5) + [0, 0, DOOR_HEIGHT + 0.05]
            b.add(_KEEPOUT, [make_part("box", c, np.zeros(3), size=size)])
    return ids


def _along(side: str, W: float, D: float, center: np.ndarray) -> float:
    """The offset along wall ``side`` (as :func:`against_wall` takes it) of a point."""
    p, n, _, _ = wall_frame(side, W, D)
    return float((np.asarray(center) - p)[:2] @ np.array([-n[1], n[0]]))


def _wall_piece(b: SceneBuilder, cls: str, make, size, W: float, D: float, floor: int, margin: float = 0.1):
    """A piece of furniture of ``size`` (length along the wall, depth, height) against a random wall:
    ``make(center, yaw, size) -> (parts, tops)``; (object, side, centre, yaw) or None when it found no
    place."""
    size = np.asarray(size, dtype=np.float64)
    for _ in range(40):
        spot = furniture_spot(b, _SIDES, W, D, size[:2])
        if spot is None:
            continue
        center, yaw, side = spot
        parts, tops = make(center, yaw, size)
        obj = b.try_add(cls, parts, floor, "on", tops, margin=margin)
        if obj is not None:
            return obj, side, center, yaw
    return None


def _cabinet_piece(b: SceneBuilder, cls: str, base, jitter: float, size, W: float, D: float, floor: int):
    """A closed box of furniture (:func:`~.procedural.cabinet_parts`) of colour ``base`` +- ``jitter``
    against a random wall, as :func:`_wall_piece` places it."""
    return _wall_piece(
        b, cls, lambda c, y, s: cabinet_parts(c, y, s, b.color(base, jitter)), size, W, D, floor
    )


def _on_top(b: SceneBuilder, support: SceneObject | None, classes, k: tuple[int, int]) -> None:
    """``k`` = (at least, at most) random ``classes`` on the support's first top surface."""
    if support is None or not support.top_surfaces:
        return
    n = int(b.rng.integers(k[0], k[1] + 1))
    for cls in b.rng.choice(list(classes), size=min(n, len(classes)), replace=False):
        place_small(b, str(cls), support, support.top_surfaces[0])


def _bed(center, yaw, size, col) -> tuple[list[Part], list]:
    """A bed of ``size`` (width along the wall, length, mattress top height), its headboard on the wall."""
    width, length, top = size
    parts = [
        make_part("box", center + [0, 0, 0.15], col, size=rotated_size([length, width, 0.3], yaw)),
        make_part(
            "box",
            local_point(center, yaw, [0.02, 0, 0.3 + (top - 0.3) / 2]),
            np.array([0.92, 0.9, 0.86]),
            size=rotated_size([length - 0.08, width - 0.06, top - 0.3], yaw),
            texture=TEXTURE_NOISE,
            texture_scale=0.1,
        ),
        make_part(
            "box",
            local_point(center, yaw, [-length / 2 + 0.04, 0, 0.5]),
            col * 0.85,
            size=rotated_size([0.08, width, 1.0], yaw),
        ),
    ]
    mid = local_point(center, yaw, [0.06, 0, 0])[:2]
    half = rotated_size([length - 0.3, width - 0.1, 0], yaw)[:2] / 2
    return parts, [(mid - half, mid + half, top)]


def _toilet(center, yaw, size, col) -> tuple[list[Part], list]:
    """A toilet facing into the room: bowl, seat and the tank against the wall."""
    _, depth, _ = size
    bowl_c = local_point(center, yaw, [0.08, 0, 0])
    return [
        make_part("cylinder", bowl_c, col, radius=0.17, radius_top=0.2, height=0.4),
        make_part(
            "box",
            local_point(center, yaw, [-depth / 2 + 0.1, 0, 0.6]),
            col,
            size=rotated_size([0.2, 0.42, 0.4], yaw),
        ),
    ], []


def _bathtub(center, yaw, size, col) -> tuple[list[Part], list]:
    """An open tub: a bottom and four rims (its inside shows from above)."""
    L, Dp, Ht = size
    r = 0.08
    parts = [make_part("box", center + [0, 0, 0.05], col, size=rotated_size([Dp, L, 0.1], yaw))]
    for s in (-1, 1):
        parts.append(
            make_part(
                "box",
                local_point(center, yaw, [s * (Dp / 2 - r / 2), 0, Ht / 2]),
                col,
                size=rotated_size([r, L, Ht], yaw),
            )
        )
        parts.append(
            make_part(
                "box",
                local_point(center, yaw, [0, s * (L / 2 - r / 2), Ht / 2]),
                col * 0.97,
                size=rotated_size([Dp - 2 * r, r, Ht], yaw),
            )
        )
    return parts, []


def _free_spot(b: SceneBuilder, W: float, D: float, wall_gap: float) -> np.ndarray:
    """A random floor point at least ``wall_gap`` from the walls."""
    return np.array(
        [
            b.rng.uniform(-W / 2 + wall_gap, W / 2 - wall_gap),
            b.rng.uniform(-D / 2 + wall_gap, D / 2 - wall_gap),
            0.0,
        ]
    )


def _attached(
    b: SceneBuilder,
    cls: str,
    wall: int,
    side: str,
    W: float,
    D: float,
    along: float,
    z0: float,
    w: float,
    h: float,
    color,
) -> SceneObject | None:
    """A thin box (mirror, towel) on wall ``side`` at offset ``along``, its bottom at ``z0``."""
    p, n, _, yaw = wall_frame(side, W, D)
    t_axis = np.array([-n[1], n[0], 0.0])
    c = p + n * 0.015 + t_axis * along + [0, 0, z0 + h / 2]
    part = make_part("box", c, color, size=rotated_size([0.03, w, h], yaw))
    return b.try_add(cls, [part], wall, "attached to", margin=0.03)


def _bookshelf(b: SceneBuilder, W: float, D: float, floor: int, size, boards: int) -> None:
    """A bookshelf of ``size`` with ``boards`` boards against a random wall, books on every board."""
    shelf = _wall_piece(
        b,
        "bookshelf",
        lambda c, y, s: shelf_parts(c, y, s, b.color((0.55, 0.38, 0.22)), boards),
        size,
        W,
        D,
        floor,
    )
    if shelf is not None:
        for top in shelf[0].top_surfaces:
            add_books_in_shelf(b, shelf[0], top)


def _living_room(b: SceneBuilder, ids: dict[str, int], W: float, D: float) -> None:
    floor, rng = ids["floor"], b.rng
    sofa = _wall_piece(
        b,
        "sofa",
        lambda c, y, s: sofa_parts(c, y, s, b.color((0.35, 0.4, 0.55), 0.12)),
        [rng.uniform(1.8, 2.2), 0.85, 0.85],
        W,
        D,
        floor,
        margin=0.15,
    )
    if sofa is not None:
        obj, side, center, yaw = sofa
        for _ in range(int(rng.integers(1, 3))):
            place_small(b, "pillow", obj, obj.top_surfaces[0])
        n = wall_frame(side, W, D)[1]
        tc = center + n * (0.85 / 2 + 0.45 + 0.3)
        parts, tops = table_parts(tc, yaw + np.pi / 2, [1.0, 0.55, 0.45], b.color((0.5, 0.35, 0.22)))
        table = b.try_add("table", parts, floor, "on", tops, margin=0.05)
        _on_top(b, table, ["cup", "book", "vase", "bowl"], (1, 3))
    stand = _cabinet_piece(
        b, "cabinet", (0.3, 0.25, 0.2), 0.08, [rng.uniform(1.2, 1.6), 0.45, 0.5], W, D, floor
    )
    if stand is not None:
        obj, _, center, yaw = stand
        parts, _ = small_object_parts(b, "tv", 2.0)
        turn = yaw_matrix(yaw + np.pi / 2)
        top = obj.top_surfaces[0][2]
        moved = [
            Part(
                p.vertices @ turn.T + [center[0], center[1], top],
                p.triangles,
                p.color,
                p.texture,
                p.texture_scale,
            )
            for p in parts
        ]
        b.try_add("tv", moved, obj.instance_id, "on", margin=0.0)
    _bookshelf(b, W, D, floor, [rng.uniform(0.8, 1.1), 0.34, rng.uniform(1.5, 1.8)], 3)


def _kitchen(b: SceneBuilder, ids: dict[str, int], W: float, D: float) -> None:
    floor, rng = ids["floor"], b.rng
    counter = _cabinet_piece(
        b, "counter", (0.8, 0.78, 0.72), 0.06, [rng.uniform(1.6, 2.2), 0.6, 0.9], W, D, floor
    )
    if counter is not None:
        place_small(b, "sink", counter[0], counter[0].top_surfaces[0])
        _on_top(b, counter[0], ["bottle", "bowl", "cup", "box"], (1, 3))
    _cabinet_piece(b, "refrigerator", (0.9, 0.9, 0.92), 0.03, [0.7, 0.7, rng.uniform(1.7, 1.9)], W, D, floor)
    _cabinet_piece(b, "stove", (0.2, 0.2, 0.22), 0.03, [0.6, 0.6, 0.9], W, D, floor)
    for _ in range(30):
        size = np.array([rng.uniform(1.0, 1.2), rng.uniform(0.7, 0.8), 0.75])
        yaw = float(rng.integers(2)) * np.pi / 2
        parts, tops = table_parts(_free_spot(b, W, D, 1.0), yaw, size, b.color((0.6, 0.42, 0.26)))
        table = b.try_add("table", parts, floor, "on", tops, margin=0.55)
        if table is not None:
            lo, hi = table.aabb
            mid = (lo + hi) / 2
            short = 1 - int(np.argmax((hi - lo)[:2]))  # chairs face the table across its short axis
            color = b.color((0.3, 0.22, 0.15), 0.08)
            for sgn in (-1, 1):
                c = np.array([mid[0], mid[1], 0.0])
                c[short] = (hi if sgn > 0 else lo)[short] + sgn * 0.3
                chair_yaw = np.arctan2(0, -sgn) if short == 0 else np.arctan2(-sgn, 0)
                b.try_add("chair", chair_parts(c, chair_yaw, color), floor, "on", margin=0.05)
            _on_top(b, table, ["bowl", "cup", "bottle"], (1, 2))
            break


def _bedroom(b: SceneBuilder, ids: dict[str, int], W: float, D: float) -> None:
    floor, rng = ids["floor"], b.rng
    bed = None
    for width in (rng.uniform(1.4, 1.6), rng.uniform(0.9, 1.0)):  # a double bed, else a single one
        bed = _wall_piece(
            b,
            "bed",
            lambda c, y, s: _bed(c, y, s, b.color((0.45, 0.32, 0.22))),
            [width, rng.uniform(1.95, 2.1), 0.5],
            W,
            D,
            floor,
            margin=0.2,
        )
        if bed is not None:
            break
    if bed is not None:
        obj, side, center, _ = bed
        for _ in range(int(rng.integers(1, 3))):
            place_small(b, "pillow", obj, obj.top_surfaces[0])
        along = _along(side, W, D, center)
        for sgn in (-1, 1):
            c, yaw = against_wall(side, W, D, 0.4, along + sgn * (width / 2 + 0.3))
            parts, tops = cabinet_parts(c, yaw, [0.45, 0.4, 0.55], b.color((0.5, 0.36, 0.24)))
            stand = b.try_add("nightstand", parts, floor, "on", tops, margin=0.02)
            _on_top(b, stand, ["lamp", "book", "cup"], (1, 1))
    _cabinet_piece(
        b,
        "wardrobe",
        (0.7, 0.6, 0.48),
        0.06,
        [rng.uniform(1.0, 1.4), 0.6, rng.uniform(1.9, 2.05)],
        W,
        D,
        floor,
    )


def _bathroom(b: SceneBuilder, ids: dict[str, int], W: float, D: float) -> None:
    floor, rng = ids["floor"], b.rng
    white = np.array([0.93, 0.93, 0.92])
    _wall_piece(b, "toilet", lambda c, y, s: _toilet(c, y, s, white), [0.45, 0.7, 0.8], W, D, floor)
    vanity = _cabinet_piece(
        b, "cabinet", (0.55, 0.45, 0.35), 0.06, [rng.uniform(0.6, 0.9), 0.45, 0.82], W, D, floor
    )
    if vanity is not None:
        obj, side, center, _ = vanity
        place_small(b, "sink", obj, obj.top_surfaces[0])
        _attached(
            b,
            "mirror",
            ids[side],
            side,
            W,
            D,
            _along(side, W, D, center),
            1.2,
            0.55,
            0.75,
            b.color((0.7, 0.78, 0.82), 0.03),
        )
    _wall_piece(
        b,
        "bathtub",
        lambda c, y, s: _bathtub(c, y, s, white * 0.98),
        [rng.uniform(1.5, 1.7), 0.75, 0.55],
        W,
        D,
        floor,
    )
    for _ in range(30):
        side = _SIDES[rng.integers(4)]
        half = wall_frame(side, W, D)[2]
        if (
            _attached(
                b,
                "towel",
                ids[side],
                side,
                W,
                D,
                rng.uniform(-half + 0.4, half - 0.4),
                0.8,
                0.45,
                0.7,
                b.vivid(),
            )
            is not None
        ):
            break
    for _ in range(30):
        side = _SIDES[rng.integers(4)]
        half = wall_frame(side, W, D)[2]
        c, _ = against_wall(side, W, D, 0.3, rng.uniform(-half + 0.3, half - 0.3))
        can = [make_part("cylinder", c, b.color((0.5, 0.52, 0.55)), radius=0.13, height=0.3)]
        if b.try_add("trash can", can, floor, "on", margin=0.05) is not None:
            break


def _office(b: SceneBuilder, ids: dict[str, int], W: float, D: float) -> None:
    floor, rng = ids["floor"], b.rng
    depth = rng.uniform(0.65, 0.75)
    desk = _wall_piece(
        b,
        "desk",
        lambda c, y, s: table_parts(c, y, [s[1], s[0], s[2]], b.color((0.45, 0.3, 0.2))),
        [rng.uniform(1.2, 1.6), depth, 0.75],
        W,
        D,
        floor,
        margin=0.2,
    )
    if desk is not None:
        obj, side, center, yaw = desk
        _on_top(b, obj, ["monitor", "laptop", "lamp", "cup", "book"], (2, 4))
        n = wall_frame(side, W, D)[1]
        b.try_add(
            "chair",
            chair_parts(center + n * (depth / 2 + 0.35), yaw + np.pi, b.color((0.15, 0.15, 0.17), 0.03)),
            floor,
            "on",
            margin=0.02,
        )
    _bookshelf(b, W, D, floor, [rng.uniform(0.8, 1.2), 0.34, rng.uniform(1.6, 1.85)], 4)
    cab = _cabinet_piece(
        b,
        "cabinet",
        (0.85, 0.83, 0.78),
        0.1,
        [rng.uniform(0.8, 1.1), 0.45, rng.uniform(0.7, 0.85)],
        W,
        D,
        floor,
    )
    if cab is not None:
        _on_top(b, cab[0], ["box", "plant", "book", "vase"], (1, 2))


_FURNISH = {
    "living room": _living_room,
    "kitchen": _kitchen,
    "bedroom": _bedroom,
    "bathroom": _bathroom,
    "office": _office,
}


def _build_one(
    rng,
    kind: str,
    W: float,
    D: float,
    H: float,
    doors: dict[str, list[float]],
    entrance: bool,
    switch_seed: int,
) -> SceneBuilder:
    """One furnished room centred on the origin (z-up), keep-out boxes included."""
    b = SceneBuilder(rng)
    ids = _room_shell(b, W, D, H, doors)
    _FURNISH[kind](b, ids, W, D)
    exterior = [s for s in _SIDES if s not in doors]
    decor = (
        (["door"] if entrance else [])
        + ["window", "picture"]
        + (["picture", "clock"] if kind != "bathroom" else [])
    )
    for cls in decor:
        for _ in range(30):
            side = (
                exterior[rng.integers(len(exterior))]
                if cls in ("door", "window")
                else _SIDES[rng.integers(4)]
            )
            parts = decoration_parts(b, cls, side, W, D)
            if parts is not None and b.try_add(cls, parts, ids[side], "attached to", margin=0.05) is not None:
                if cls == "door":
                    b.extra_relations.append((b.objects[-1].instance_id, "on", ids["floor"]))
                break
    add_light_switches(b, ids, W, D, switch_seed)
    if kind in ("living room", "bedroom", "office"):
        add_floor_lamp(b, ids, W, D)
    return b


# --------------------------------------------------------------------------------------- the apartment


def build_apartment(seed: int = 0) -> Apartment:
    """A deterministic random apartment for ``seed``: 2-5 rooms of distinct types in a row (see the module
    docstring), in the world frame (up = -y), centred on the origin."""
    rng = np.random.default_rng(np.random.SeedSequence([seed, 0xA9A27]))
    n = int(rng.integers(2, 6))
    kinds = [str(k) for k in rng.permutation(ROOM_TYPES)[:n]]
    H = float(rng.uniform(2.5, 2.8))
    dims = [(rng.uniform(*ROOM_SIZES[k][0]), rng.uniform(*ROOM_SIZES[k][1])) for k in kinds]
    t = WALL_THICKNESS
    x0s = np.cumsum([0.0] + [W + 2 * t for W, _ in dims[:-1]])
    door_y = [
        rng.uniform(0.6 + DOOR_WIDTH / 2, min(dims[i][1], dims[i + 1][1]) - 0.6 - DOOR_WIDTH / 2)
        for i in range(n - 1)
    ]
    total = (x0s[-1] + dims[-1][0], max(D for _, D in dims))
    shift = -np.array(total) / 2
    merged = SceneBuilder(rng)
    rooms, instance_room, doors = [], {}, []
    for i, (kind, (W, D)) in enumerate(zip(kinds, dims)):
        lo = np.array([x0s[i], 0.0]) + shift
        hi = lo + [W, D]
        center = (lo + hi) / 2
        local_doors: dict[str, list[float]] = {}
        if i > 0:
            local_doors["-x"] = [door_y[i - 1] + shift[1] - center[1]]
        if i < n - 1:
            local_doors["+x"] = [door_y[i] + shift[1] - center[1]]
            doors.append((i + 1, i + 2, np.array([hi[0] + t, door_y[i] + shift[1]])))
        sub = np.random.default_rng(np.random.SeedSequence([seed, 0xA9A27, i]))
        b = _build_one(sub, kind, W, D, H, local_doors, i == 0, seed * 8 + i)
        _merge(merged, b, np.array([center[0], center[1], 0.0]), i + 1, instance_room)
        corners = np.array([[lo[0], lo[1], 0.0], [hi[0], hi[1], H]]) @ WORLD_FROM_ZUP.T
        rooms.append(ApartmentRoom(i + 1, kind, 0, corners.min(0), corners.max(0), lo, hi))
    room = finish_room(merged, (float(total[0]), float(total[1]), H), np.array([0.0, 0.0, H - 0.3]))
    base = {f.name: getattr(room, f.name) for f in fields(Room)}
    return Apartment(**base, rooms=rooms, instance_room=instance_room, doors=doors)


def _merge(
    into: SceneBuilder, b: SceneBuilder, offset: np.ndarray, room_id: int, instance_room: dict[int, int]
) -> None:
    """Move ``b``'s objects (keep-outs left out) by ``offset`` into ``into`` with new instance ids."""
    new_id: dict[int, int] = {}
    for obj in b.objects:
        if obj.class_name != _KEEPOUT:
            new_id[obj.instance_id] = len(into.objects) + len(new_id) + 1
    for obj in b.objects:
        if obj.class_name == _KEEPOUT:
            continue
        parts = [
            Part(p.vertices + offset, p.triangles, p.color, p.texture, p.texture_scale) for p in obj.parts
        ]
        tops = [(lo + offset[:2], hi + offset[:2], *rest) for lo, hi, *rest in obj.top_surfaces]
        support = new_id.get(obj.support) if obj.support is not None else None
        into.objects.append(
            SceneObject(new_id[obj.instance_id], obj.class_name, parts, support, obj.support_relation, tops)
        )
        instance_room[new_id[obj.instance_id]] = room_id
    into.extra_relations += [(new_id[s], r, new_id[o]) for s, r, o in b.extra_relations]


# --------------------------------------------------------------------------------------- camera path


def _occupancy(apt: Apartment, room: ApartmentRoom) -> tuple[np.ndarray, np.ndarray]:
    """(clearance in metres per grid cell of the room's interior, cell centres' origin): the distance to the
    nearest wall or furniture part standing between 5 cm and 2 m."""
    from scipy.ndimage import distance_transform_edt

    lo, hi = room.zup_min, room.zup_max
    shape = np.ceil((hi - lo) / _GRID).astype(int)
    free = np.ones(shape, dtype=bool)
    for obj in apt.zup_objects:
        if obj.class_name in STRUCTURAL_CLASSES or apt.instance_room.get(obj.instance_id) != room.id:
            continue
        for p in obj.parts:
            a, c = p.aabb
            if c[2] < 0.05 or a[2] > 2.0:
                continue
            i0, j0 = np.floor((a[:2] - lo) / _GRID).astype(int)
            i1, j1 = np.ceil((c[:2] - lo) / _GRID).astype(int)
            free[max(i0, 0) : max(i1, 0), max(j0, 0) : max(j1, 0)] = False
    padded = np.pad(free, 1, constant_values=False)  # the walls
    return distance_transform_edt(padded)[1:-1, 1:-1] * _GRID, lo


def _cell(p: np.ndarray, lo: np.ndarray, shape) -> tuple[int, int]:
    i, j = np.floor((np.asarray(p) - lo) / _GRID).astype(int)
    return int(np.clip(i, 0, shape[0] - 1)), int(np.clip(j, 0, shape[1] - 1))


def _shortest(clear: np.ndarray, start: tuple[int, int], goal: tuple[int, int] | None, need: float):
    """Dijkstra over the cells with clearance >= ``need`` (the start always passes), 8-connected, from
    ``start``: (distances [cells], parents) when ``goal`` is None, else the cell path to ``goal`` (None when
    it cannot be reached)."""
    dist = np.full(clear.shape, np.inf)
    parent = -np.ones(clear.shape + (2,), dtype=int)
    dist[start] = 0.0
    heap = [(0.0, start)]
    steps = [(di, dj, float(np.hypot(di, dj))) for di in (-1, 0, 1) for dj in (-1, 0, 1) if di or dj]
    while heap:
        d, (i, j) = heapq.heappop(heap)
        if d > dist[i, j]:
            continue
        if goal is not None and (i, j) == goal:
            break
        for di, dj, w in steps:
            a, c = i + di, j + dj
            if not (0 <= a < clear.shape[0] and 0 <= c < clear.shape[1]) or clear[a, c] < need:
                continue
            nd = d + w * (1.0 + 0.3 / max(clear[a, c], 0.05))  # keep to the middle of free space
            if nd < dist[a, c]:
                dist[a, c], parent[a, c] = nd, (i, j)
                heapq.heappush(heap, (nd, (a, c)))
    if goal is None:
        return dist, parent
    if not np.isfinite(dist[goal]):
        return None
    path, cur = [goal], goal
    while cur != start:
        cur = tuple(int(v) for v in parent[cur])
        path.append(cur)
    return path[::-1]


def _simplify(points: np.ndarray, clear_at) -> np.ndarray:
    """Drop polyline vertices while the straight segment between the kept ones stays clear."""
    out, k = [points[0]], 0
    while k < len(points) - 1:
        nxt = k + 1
        for m in range(len(points) - 1, k + 1, -1):
            seg = np.linspace(
                points[k], points[m], max(2, int(np.linalg.norm(points[m] - points[k]) / _GRID) + 1)
            )
            if all(clear_at(p) for p in seg):
                nxt = m
                break
        out.append(points[nxt])
        k = nxt
    return np.asarray(out)


def _room_route(apt: Apartment, room: ApartmentRoom, entry, exit_) -> tuple[list[np.ndarray], np.ndarray]:
    """The route through one room: (polyline from ``entry`` to the station, polyline from the station to
    ``exit_``) as z-up (x, y) points; ``entry`` / ``exit_`` None for the first / last room. The station is the
    most open reachable spot near the room's middle, where the camera turns around."""
    clear, lo = _occupancy(apt, room)
    source = entry if entry is not None else exit_
    mid = (room.zup_min + room.zup_max) / 2
    centers = (
        lo
        + (
            np.stack(np.meshgrid(np.arange(clear.shape[0]), np.arange(clear.shape[1]), indexing="ij"), -1)
            + 0.5
        )
        * _GRID
    )
    if source is None:  # a single-room apartment never happens (2-5 rooms), but stay defined
        station = centers[np.unravel_index(np.argmax(clear), clear.shape)]
        return [station[None]], station[None]
    dist, _ = _shortest(clear, _cell(source, lo, clear.shape), None, _CLEARANCE)
    score = np.minimum(clear, 1.2) - 0.15 * np.linalg.norm(centers - mid, axis=-1)
    score[~np.isfinite(dist)] = -np.inf
    station = centers[np.unravel_index(np.argmax(score), score.shape)]

    def clear_at(p) -> bool:
        return bool(clear[_cell(p, lo, clear.shape)] >= _CLEARANCE - 0.05)

    def route(a, c) -> np.ndarray:
        cells = _shortest(clear, _cell(a, lo, clear.shape), _cell(c, lo, clear.shape), _CLEARANCE)
        if cells is None:  # (cannot happen: the station was chosen among the reachable cells)
            return np.array([a, c])
        pts = np.array([a] + [lo + (np.array(q) + 0.5) * _GRID for q in cells[1:-1]] + [c])
        return _simplify(pts, clear_at)

    into = route(entry, station) if entry is not None else station[None]
    out = route(station, exit_) if exit_ is not None else station[None]
    return into, out


def _turn(a: float, b: float) -> float:
    """The signed smallest turn from yaw ``a`` to yaw ``b``."""
    return float((b - a + np.pi) % (2 * np.pi) - np.pi)


def apartment_path(apt: Apartment, seed: int) -> np.ndarray:
    """The camera path as dense samples [M, 3] of (x, y, yaw) in the z-up frame: walking segments look ahead,
    turns happen on the spot, and at each room's station the camera turns once all around."""
    rng = np.random.default_rng(np.random.SeedSequence([seed, 0x7EA, 1]))
    samples: list[tuple[float, float, float]] = []

    def walk(points: np.ndarray) -> None:
        for a, c in zip(points[:-1], points[1:]):
            length = float(np.linalg.norm(c - a))
            if length < 1e-6:
                continue
            turn_to(float(np.arctan2(*(c - a)[::-1])))
            heading = samples[-1][2]  # unwrapped: the yaw stays continuous along the path
            for s in np.linspace(0.0, 1.0, max(2, int(length / 0.01)))[1:]:
                p = a + s * (c - a)
                samples.append((float(p[0]), float(p[1]), heading))

    def turn_to(yaw: float, full: float = 0.0) -> None:
        x, y, y0 = samples[-1]
        delta = _turn(y0, yaw) + full
        for s in np.linspace(0.0, 1.0, max(2, int(abs(delta) / np.deg2rad(0.5))))[1:]:
            samples.append((x, y, y0 + s * delta))

    ends = {}
    for a, c, xy in apt.doors:
        ends[a] = (ends.get(a, (None, None))[0], xy - [0.55, 0.0])
        ends[c] = (xy + [0.55, 0.0], ends.get(c, (None, None))[1])
    for k, room in enumerate(apt.rooms):
        entry, exit_ = ends.get(room.id, (None, None))
        into, out = _room_route(apt, room, entry, exit_)
        if k == 0:
            samples.append((float(into[0][0]), float(into[0][1]), float(rng.uniform(0, 2 * np.pi))))
        else:
            walk(np.array([samples[-1][:2], into[0]]))  # through the doorway
            walk(np.asarray(into))
        x, y, yaw = samples[-1]
        turn_to(yaw, (1.0 if rng.uniform() < 0.5 else -1.0) * 2 * np.pi)  # once all around
        walk(np.asarray(out))
    return np.asarray(samples)


def apartment_camera(
    apt: Apartment, frames_per_room: int, seed: int, max_step_m: float = 0.35, max_step_deg: float = 20.0
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The camera of ``frames_per_room`` x rooms frames along :func:`apartment_path`, spread evenly over its
    length and turning (a metre walked counts as much as 60 degrees turned), at about 1.45 m height, looking
    ~20 degrees down: (positions [F, 3] in the z-up frame, yaw [F], pitch [F] in radians). ValueError when
    too few frames would step farther than ``max_step_m`` or turn more than ``max_step_deg`` between
    frames."""
    frames = int(frames_per_room) * len(apt.rooms)
    path = apartment_path(apt, seed)
    step = np.hypot(*np.diff(path[:, :2], axis=0).T)
    turn = np.abs(np.diff(path[:, 2]))
    cost = np.concatenate([[0.0], np.cumsum(np.maximum(step, turn / np.deg2rad(60.0)))])
    s = np.linspace(0.0, cost[-1], frames)
    x, y = np.interp(s, cost, path[:, 0]), np.interp(s, cost, path[:, 1])
    yaw = np.interp(s, cost, path[:, 2])
    if frames > 1:
        worst_m = float(np.max(np.hypot(np.diff(x), np.diff(y))))
        worst_deg = float(np.rad2deg(np.max(np.abs(np.diff(yaw)))))
        if worst_m > max_step_m or worst_deg > max_step_deg:
            need = int(np.ceil(frames * max(worst_m / max_step_m, worst_deg / max_step_deg) / len(apt.rooms)))
            raise ValueError(
                f"an apartment of {len(apt.rooms)} rooms needs at least {need} frames per room for steps of "
                f"at most {max_step_m} m and {max_step_deg} degrees (got {frames_per_room})"
            )
    rng = np.random.default_rng(np.random.SeedSequence([seed, 0x7EA, 2]))
    u = np.linspace(0.0, 1.0, frames)
    height = rng.uniform(1.4, 1.5) + 0.04 * np.sin(2 * np.pi * 3.0 * u)
    pitch = -0.35 + 0.08 * np.sin(2 * np.pi * 5.0 * u)
    return np.stack([x, y, height], -1), yaw, pitch


def rooms_entered(apt: Apartment, poses: np.ndarray) -> dict[int, int]:
    """{room id: the first frame whose camera stands inside the room's interior} (rooms never entered are
    left out)."""
    out: dict[int, int] = {}
    pos = poses[:, :3, 3] @ WORLD_FROM_ZUP  # world -> z-up (the matrix is orthogonal)
    for room in apt.rooms:
        inside = np.all((pos[:, :2] >= room.zup_min) & (pos[:, :2] <= room.zup_max), axis=1)
        if inside.any():
            out[room.id] = int(np.argmax(inside))
    return out
