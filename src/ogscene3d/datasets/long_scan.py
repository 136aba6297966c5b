"""Long scans (``synthetic.layout: scan``): a larger furnished room, scanned as a real ScanNet sequence is.

What differs from the default single room (:mod:`.procedural`, ``synthetic.layout: room``):

* the room (:func:`build_scan_room`): about 7 x 6 m and 55 to 75 objects. Its large furniture stands on the
  floor in groups along the walls, piece next to piece (a refrigerator beside the kitchen counter, side tables
  beside the sofa, nightstands beside the bed, a desk beside the bookshelf), with a coffee table, a dining
  table with chairs, a TV on its cabinet and the usual smaller objects;
* the camera path (:func:`scan_trajectory`): it walks through the free floor from one furniture group to
  the next, pans along each, leaves it and comes back to it later; frames lie irregularly along the path,
  most a few centimetres or degrees apart, some jumps of up to :data:`MAX_JUMP_M` / :data:`MAX_JUMP_DEG`
  (a real scan's frames after subsampling and dropped frames);
* first-view merges (:func:`plan_first_view_merges`): an object standing on the floor or on a large piece of
  furniture is, with a seeded probability per object (the noise level's ``first_view_merge_prob``),
  under-segmented in its first :data:`FIRST_VIEWS` views with the floor, with the large furniture standing
  next to it, or with the furniture it stands on, as SAM merges a refrigerator with the floor in the view
  that first shows it. The simulated SAM applies the plan (``segmentation/simulated.py``); the scene keeps it
  in ``gt/first_views.json``.

Everything is seeded, and the builder works in the z-up frame of :mod:`.procedural`.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from functools import partial

import numpy as np

from .._disjoint_sets import DisjointSets
from .procedural import (
    STRUCTURAL_CLASSES,
    TEXTURE_NOISE,
    TEXTURE_PLAIN,
    TEXTURE_STRIPES,
    WORLD_FROM_ZUP,
    Part,
    Room,
    SceneBuilder,
    SceneObject,
    add_books_in_shelf,
    add_light_switches,
    add_structure,
    against_wall,
    chair_parts,
    chair_slots,
    finish_room,
    local_point,
    make_part,
    place_small,
    rotated_size,
    shelf_parts,
    table_parts,
    wall_frame,
)

# furniture that stands on the floor and that SAM may merge with the floor or with its neighbour
LARGE_FURNITURE = (
    "refrigerator", "counter", "cabinet", "sofa", "bed", "table", "desk", "bookshelf", "nightstand",
)  # fmt: skip
ADJACENT_GAP = 0.05  # metres: large furniture this close stands next to each other
MAX_JUMP_M = 1.5  # the largest step between consecutive frames
MAX_JUMP_DEG = 60.0
JUMP_PROB = 0.05  # share of the steps that are jumps
SMALL_STEP = 0.1  # about the mean small step: metres of walk plus metres-equivalent of turn (see _motion)
FIRST_VIEWS = 3  # an object's first views, which a first-view merge under-segments
FIRST_VIEW_AREA = 0.001  # share of the image from which a view counts as showing the object
_SIDES = ("+x", "-x", "+y", "-y")
_WALKWAY = 0.35  # metres kept free between furniture groups (the camera walks there)


# --------------------------------------------------------------------------------------- the room


def _boxy(center, yaw, size, color, fronts: int, top_slab: bool = False, texture: int = TEXTURE_PLAIN):
    """A box-shaped piece (refrigerator, counter, cabinet, nightstand) of ``size`` (length along the wall,
    depth, height) standing at ``center`` with its front to local +x: the body, ``fronts`` door or drawer
    panels stacked on the front, a worktop slab. Returns (parts, tops)."""
    L, Dp, Ht = size
    body_h = Ht - (0.04 if top_slab else 0.0)
    parts = [make_part("box", center + [0, 0, body_h / 2], color, size=rotated_size([Dp, L, body_h], yaw),
                       texture=texture, texture_scale=0.12)]  # fmt: skip
    edges = np.linspace(0.04, body_h - 0.03, fronts + 1)
    for lo, hi in zip(edges[:-1], edges[1:]):
        c = local_point(center, yaw, [Dp / 2 + 0.006, 0, (lo + hi) / 2])
        parts.append(
            make_part("box", c, color * 0.88, size=rotated_size([0.012, L * 0.9, (hi - lo) - 0.02], yaw))
        )
    if top_slab:
        c = local_point(center, yaw, [0.01, 0, Ht - 0.02])
        parts.append(make_part("box", c, color * 0.6, size=rotated_size([Dp + 0.02, L, 0.04], yaw)))
    half = rotated_size([Dp, L, 0], yaw)[:2] / 2
    return parts, [(center[:2] - half, center[:2] + half, Ht)]


def _sofa_with_cushions(center, yaw, size, color):
    """A sofa of ``size`` (length, depth, height): plinth, back, arms and three seat cushions."""
    L, Dp, Ht = size
    back, arm, seat = 0.22, 0.16, 0.3
    parts = [
        make_part("box", center + [0, 0, seat / 2], color * 0.8, size=rotated_size([Dp, L, seat], yaw)),
        make_part("box", local_point(center, yaw, [-Dp / 2 + back / 2, 0, (Ht + seat) / 2]), color,
                  size=rotated_size([back, L, Ht - seat], yaw)),
    ]  # fmt: skip
    for s in (-1, 1):
        c = local_point(center, yaw, [back / 2, s * (L / 2 - arm / 2), seat + 0.16])
        parts.append(make_part("box", c, color * 0.92, size=rotated_size([Dp - back, arm, 0.32], yaw)))
    width = (L - 2 * arm) / 3
    for k in (-1, 0, 1):
        c = local_point(center, yaw, [back / 2, k * width, seat + 0.07])
        size = rotated_size([Dp - back - 0.02, width - 0.01, 0.14], yaw)
        parts.append(make_part("box", c, color * 1.05, size=size, texture=TEXTURE_NOISE, texture_scale=0.06))
    inner = rotated_size([Dp - back - 0.1, L - 2 * arm - 0.05, 0], yaw)[:2] / 2
    mid = local_point(center, yaw, [back / 2, 0, 0])[:2]
    return parts, [(mid - inner, mid + inner, seat + 0.14)]


def _bed(center, yaw, size, color):
    """A bed of ``size`` (width along the wall, length into the room with the headboard, height of the
    mattress top): frame, mattress, headboard. Pillows go on the head end of the mattress."""
    Wd, Ln, Ht = size
    head = 0.06
    body = Ln - head
    mid = local_point(center, yaw, [head / 2, 0, 0])
    parts = [
        make_part("box", mid + [0, 0, 0.15], color * 0.7, size=rotated_size([body, Wd, 0.3], yaw)),
        make_part("box", mid + [0, 0, 0.3 + (Ht - 0.3) / 2], np.clip(0.35 * color + 0.55, 0, 1),
                  size=rotated_size([body - 0.04, Wd - 0.04, Ht - 0.3], yaw), texture=TEXTURE_NOISE,
                  texture_scale=0.1),
        make_part("box", local_point(center, yaw, [-Ln / 2 + head / 2, 0, 0.5]), color * 0.6,
                  size=rotated_size([head, Wd, 1.0], yaw)),
    ]  # fmt: skip
    lo = local_point(center, yaw, [-Ln / 2 + head + 0.05, -(Wd / 2 - 0.06), 0])[:2]
    hi = local_point(center, yaw, [-Ln / 2 + head + 0.55, Wd / 2 - 0.06, 0])[:2]
    return parts, [(np.minimum(lo, hi), np.maximum(lo, hi), Ht)]


@dataclass
class _Piece:
    cls: str
    length: float  # along the wall
    depth: float  # into the room
    make: Callable[[np.ndarray, float], tuple[list[Part], list]]  # (centre, yaw) -> parts, tops


def _zone_pieces(b: SceneBuilder, zone: str) -> list[_Piece]:
    """The large furniture of a zone, in its order along the wall (each next to the one before)."""
    rng, c = b.rng, b.color
    if zone == "kitchen":
        fridge = np.array([0.7, 0.68, rng.uniform(1.75, 1.9)])
        counter = np.array([rng.uniform(1.3, 1.8), 0.6, 0.9])
        white, wood = c((0.88, 0.88, 0.86), 0.04), c((0.5, 0.36, 0.24))
        pieces = [
            _Piece("refrigerator", *fridge[:2], partial(_boxy, size=fridge, color=white, fronts=2)),
            _Piece("counter", *counter[:2], partial(_boxy, size=counter, color=wood, fronts=2, top_slab=True,
                                                    texture=TEXTURE_NOISE)),
        ]  # fmt: skip
        return pieces[::-1] if rng.uniform() < 0.5 else pieces
    if zone == "living":
        side = np.array([0.45, 0.45, rng.uniform(0.5, 0.6)])
        sofa = np.array([rng.uniform(1.9, 2.3), 0.9, 0.85])
        wood, cloth = c((0.45, 0.3, 0.2)), c((0.3, 0.38, 0.5), 0.12)
        side_table = _Piece("table", *side[:2], partial(table_parts, size=side[[1, 0, 2]], color=wood))
        couch = _Piece("sofa", *sofa[:2], partial(_sofa_with_cushions, size=sofa, color=cloth))
        return [side_table, couch, side_table] if rng.uniform() < 0.6 else [side_table, couch]
    if zone == "bedroom":
        bed = np.array([rng.uniform(1.4, 1.7), 2.06, 0.5])
        stand = np.array([0.45, 0.4, 0.55])
        wood, frame = c((0.55, 0.4, 0.28)), c((0.5, 0.35, 0.3))
        night = _Piece("nightstand", *stand[:2], partial(_boxy, size=stand, color=wood, fronts=2))
        return [night, _Piece("bed", *bed[:2], partial(_bed, size=bed, color=frame)), night]
    if zone == "study":
        shelf = np.array([rng.uniform(0.9, 1.1), 0.34, rng.uniform(1.6, 1.8)])
        desk = np.array([rng.uniform(1.1, 1.4), 0.6, 0.75])
        wood, top = c((0.55, 0.38, 0.22)), c((0.62, 0.5, 0.36))
        boards = int(rng.integers(3, 5))
        pieces = [
            _Piece("bookshelf", *shelf[:2], partial(shelf_parts, size=shelf, color=wood, n_boards=boards)),
            _Piece("desk", *desk[:2], partial(table_parts, size=desk[[1, 0, 2]], color=top)),
        ]
        return pieces[::-1] if rng.uniform() < 0.5 else pieces
    if zone == "tv":
        stand = np.array([rng.uniform(1.2, 1.6), 0.45, 0.5])
        dark = c((0.3, 0.3, 0.32), 0.05)
        return [_Piece("cabinet", *stand[:2], partial(_boxy, size=stand, color=dark, fronts=1))]
    raise ValueError(f"unknown zone {zone!r}")


def _place_zone(b: SceneBuilder, zone: str, W: float, D: float, tries: int = 60) -> list[SceneObject]:
    """Lay a zone's pieces along a wall, each touching the one before (gaps of 0 to 2 cm), at a random free
    spot that keeps :data:`_WALKWAY` from other furniture; [] when none is found."""
    pieces = _zone_pieces(b, zone)
    rng = b.rng
    for _ in range(tries):
        side = _SIDES[int(rng.integers(4))]
        _, _, half_len, _ = wall_frame(side, W, D)
        gaps = rng.uniform(0.0, 0.02, len(pieces))
        total = sum(p.length for p in pieces) + gaps[1:].sum()
        span = half_len - total / 2 - 0.1
        if span <= 0:
            continue
        pos = rng.uniform(-span, span) - total / 2
        placed = []
        for p, g in zip(pieces, gaps):
            pos += g if placed else 0.0
            center, yaw = against_wall(side, W, D, p.depth, pos + p.length / 2)
            parts, tops = p.make(center, yaw)
            placed.append((p.cls, parts, tops, center, yaw))
            pos += p.length
        if any(b.collides(parts, margin=_WALKWAY) for _, parts, _, _, _ in placed):
            continue
        floor = next(o for o in b.objects if o.class_name == "floor")
        return [b.add(cls, parts, floor.instance_id, "on", tops) for cls, parts, tops, _, _ in placed]
    return []


def _in_front(
    b: SceneBuilder, obj: SceneObject, cls: str, size: np.ndarray, gap: float, color, W: float, D: float
) -> SceneObject | None:
    """A table (a coffee table before the sofa, ``size`` = length, depth, height) or a chair (before the desk,
    facing it) ``gap`` metres in front of ``obj``, which stands against a wall."""
    lo, hi = obj.aabb
    center = (lo + hi) / 2
    center[2] = 0.0
    # the wall it stands against: the nearest of the four
    to_wall = [W / 2 - hi[0], lo[0] + W / 2, D / 2 - hi[1], lo[1] + D / 2]
    side = int(np.argmin(to_wall))
    axis, sgn = side // 2, (-1.0 if side % 2 == 0 else 1.0)
    front = hi[axis] if sgn > 0 else lo[axis]
    pos = center.copy()
    pos[axis] = front + sgn * (gap + (size[1] / 2 if cls == "table" else 0.22))
    yaw = (0.0 if sgn > 0 else np.pi) if axis == 0 else (np.pi / 2 if sgn > 0 else -np.pi / 2)
    floor = next(o for o in b.objects if o.class_name == "floor")
    if cls == "chair":
        return b.try_add("chair", chair_parts(pos, yaw + np.pi, color), floor.instance_id, "on", margin=0.02)
    parts, tops = table_parts(pos, yaw, size[[1, 0, 2]], color)
    return b.try_add("table", parts, floor.instance_id, "on", tops, margin=0.2)


def _dining(b: SceneBuilder, W: float, D: float) -> SceneObject | None:
    """A dining table with two to four chairs on the free floor, at least a walkway from everything else."""
    rng = b.rng
    floor = next(o for o in b.objects if o.class_name == "floor")
    for _ in range(60):
        size = np.array([rng.uniform(1.0, 1.3), rng.uniform(0.7, 0.85), 0.75])
        yaw = float(rng.integers(2)) * np.pi / 2
        center = np.array([rng.uniform(-0.35, 0.35) * W, rng.uniform(-0.35, 0.35) * D, 0.0])
        parts, tops = table_parts(center, yaw, size, b.color((0.6, 0.42, 0.26)))
        table = b.try_add("table", parts, floor.instance_id, "on", tops, margin=0.75)
        if table is None:
            continue
        lo, hi = table.aabb
        color = b.color((0.3, 0.22, 0.15), 0.08)
        slots = chair_slots(lo, hi, lambda: rng.uniform(0.28, 0.34))
        order = rng.permutation(len(slots))
        for i in order[: int(rng.integers(2, 5))]:
            b.try_add(
                "chair", chair_parts(slots[i][0], slots[i][1], color), floor.instance_id, "on", margin=0.05
            )
        return table
    return None


def _standing_extras(b: SceneBuilder, W: float, D: float) -> None:
    """A tall plant and a trash can by the walls, where there is room."""
    rng = b.rng
    floor = next(o for o in b.objects if o.class_name == "floor")
    for cls in ("plant", "trash can"):
        for _ in range(40):
            side = _SIDES[int(rng.integers(4))]
            _, _, half_len, _ = wall_frame(side, W, D)
            center, _ = against_wall(side, W, D, 0.62, rng.uniform(-half_len + 0.4, half_len - 0.4))
            if cls == "plant":
                leaves = b.color((0.2, 0.42, 0.2))
                parts = [
                    make_part("cylinder", center, b.color((0.35, 0.35, 0.38)), radius=0.18, height=0.45),
                    make_part("ellipsoid", center + [0, 0, 0.75], leaves, radii=[0.26, 0.26, 0.3],
                              texture=TEXTURE_NOISE, texture_scale=0.07),
                    make_part("ellipsoid", center + [0, 0, 1.1], leaves * 1.1, radii=[0.2, 0.2, 0.22],
                              texture=TEXTURE_NOISE, texture_scale=0.07),
                ]  # fmt: skip
            else:
                can = b.color((0.25, 0.4, 0.3))
                parts = [make_part("cylinder", center, can, radius=0.15, radius_top=0.17, height=0.4)]
            if b.try_add(cls, parts, floor.instance_id, "on", margin=0.15) is not None:
                break


def _wall_decor(b: SceneBuilder, ids: dict[str, int], W: float, D: float) -> None:
    """A door, a window, two or three pictures and a clock on the walls, clear of the furniture."""
    rng = b.rng
    # (class, width, height, bottom, thickness, colour, texture)
    items = [
        ("door", 0.9, 2.05, 0.0, 0.04, b.color((0.55, 0.4, 0.28)), TEXTURE_PLAIN),
        ("window", rng.uniform(1.0, 1.5), 1.1, 0.95, 0.03, b.color((0.6, 0.75, 0.9), 0.04), TEXTURE_STRIPES),
    ]
    items += [
        (
            "picture",
            rng.uniform(0.4, 0.8),
            rng.uniform(0.3, 0.55),
            rng.uniform(1.3, 1.6),
            0.03,
            b.vivid(),
            TEXTURE_STRIPES,
        )
        for _ in range(int(rng.integers(2, 4)))
    ]
    items.append(
        ("clock", 0.3, 0.3, rng.uniform(1.7, 1.95), 0.04, b.color((0.92, 0.92, 0.9), 0.02), TEXTURE_PLAIN)
    )
    for cls, w, h, z0, thick, col, tex in items:  # fmt: skip
        for _ in range(40):
            side = _SIDES[int(rng.integers(4))]
            p, n, half_len, yaw = wall_frame(side, W, D)
            along = rng.uniform(-half_len + w / 2 + 0.2, half_len - w / 2 - 0.2)
            c = p + n * thick / 2 + np.array([-n[1], n[0], 0.0]) * along + [0, 0, z0 + h / 2]
            part = make_part("box", c, col, size=rotated_size([thick, w, h], yaw), texture=tex,
                             texture_scale=float(rng.uniform(0.06, 0.2)))  # fmt: skip
            if b.try_add(cls, [part], ids[side], "attached to", margin=0.05) is not None:
                break


def _small_things(b: SceneBuilder, furniture: list[SceneObject]) -> None:
    """Small objects on the tops of the large furniture, pillows on the sofa and the bed, books on the
    shelves, a TV on its cabinet."""
    rng = b.rng
    choices = {
        "counter": (["bowl", "bottle", "cup", "plant", "box", "vase"], (2, 5)),
        "table": (["cup", "bottle", "bowl", "vase", "book", "laptop", "plant"], (1, 4)),
        "desk": (["book", "cup", "laptop", "lamp"], (1, 3)),
        "nightstand": (["lamp", "book", "cup"], (1, 3)),
        "sofa": (["pillow"], (1, 3)),
        "bed": (["pillow"], (2, 3)),
    }
    for obj in furniture:
        if obj.class_name == "bookshelf":
            for k, top in enumerate(obj.top_surfaces):
                if k == 0 or rng.uniform() < 0.35:
                    add_books_in_shelf(b, obj, top)
            continue
        if obj.class_name == "cabinet":
            place_small(b, "monitor", obj, obj.top_surfaces[0])
            continue
        if obj.class_name == "desk":
            place_small(b, "monitor", obj, obj.top_surfaces[0])
        if obj.class_name not in choices or not obj.top_surfaces:
            continue
        pool, (lo, hi) = choices[obj.class_name]
        n = int(rng.integers(lo, hi))
        for cls in rng.choice(pool, size=n, replace=n > len(pool) or pool == ["pillow"]):
            place_small(b, str(cls), obj, obj.top_surfaces[0])


def build_scan_room(seed: int = 0) -> Room:
    """A deterministic random furnished room for a long scan (see the module docstring), world frame."""
    rng = np.random.default_rng(np.random.SeedSequence([seed, 0x5CA7]))
    b = SceneBuilder(rng)
    W, D, H = rng.uniform(6.8, 7.8), rng.uniform(5.8, 6.6), rng.uniform(2.6, 2.9)
    ids = add_structure(b, W, D, H)
    furniture: list[SceneObject] = []
    for zone in ("bedroom", "living", "kitchen", "study", "tv"):
        placed = _place_zone(b, zone, W, D)
        furniture += placed
        if zone == "living" and placed:
            sofa = next(o for o in placed if o.class_name == "sofa")
            size = np.array([rng.uniform(1.0, 1.2), rng.uniform(0.5, 0.6), 0.42])
            coffee = _in_front(
                b, sofa, "table", size, rng.uniform(0.35, 0.45), b.color((0.5, 0.36, 0.26)), W, D
            )
            furniture += [coffee] if coffee is not None else []
        if zone == "study" and placed:
            desk = next(o for o in placed if o.class_name == "desk")
            _in_front(b, desk, "chair", np.zeros(3), 0.05, b.color((0.25, 0.25, 0.28), 0.05), W, D)
    dining = _dining(b, W, D)
    furniture += [dining] if dining is not None else []
    _standing_extras(b, W, D)
    _wall_decor(b, ids, W, D)
    _small_things(b, furniture)
    add_light_switches(b, ids, W, D, seed)
    return finish_room(b, (W, D, H), np.array([0.0, 0.0, H - 0.45]))


# --------------------------------------------------------------------------------------- the camera path


def _footprints(room: Room) -> list[tuple[np.ndarray, np.ndarray, SceneObject]]:
    """(xy min, xy max, object) of every non-structural part that a walking camera must keep clear of."""
    out = []
    for o in room.zup_objects:
        if o.class_name in STRUCTURAL_CLASSES or o.support_relation == "attached to":
            continue
        for p in o.parts:
            lo, hi = p.aabb
            out.append((lo[:2], hi[:2], o))
    return out


class _FreeFloor:
    """The floor a camera can walk (a grid of ``cell`` metres, ``clearance`` from furniture and walls), its
    largest connected part, and shortest walks on it."""

    def __init__(self, room: Room, cell: float = 0.1, clearance: float = 0.4) -> None:
        import cv2

        W, D, _ = room.size
        self.cell, self.W, self.D = cell, W, D
        nx, ny = int(np.ceil(W / cell)), int(np.ceil(D / cell))
        xs = -W / 2 + (np.arange(nx) + 0.5) * cell
        ys = -D / 2 + (np.arange(ny) + 0.5) * cell
        self.xy = np.stack(np.meshgrid(xs, ys, indexing="ij"), -1)  # [nx, ny, 2]
        occupied = np.zeros((nx, ny), bool)
        for lo, hi, _ in _footprints(room):
            occupied |= np.all((self.xy >= lo - cell / 2) & (self.xy <= hi + cell / 2), axis=-1)
        free = np.pad(~occupied, 1).astype(np.uint8)  # the walls: a border of occupied cells
        dist = cv2.distanceTransform(free, cv2.DIST_L2, 5)[1:-1, 1:-1] * cell
        # distance of a cell centre to the walls (the padding is one cell away from the first centres)
        wall = np.minimum(np.minimum(xs[:, None] + W / 2, W / 2 - xs[:, None]),
                          np.minimum(ys[None] + D / 2, D / 2 - ys[None]))  # fmt: skip
        self.clearance = np.minimum(dist, wall)
        ok = (self.clearance >= clearance).astype(np.uint8)
        n, comp = cv2.connectedComponents(ok, connectivity=8)
        sizes = np.bincount(comp.reshape(-1), minlength=n)
        sizes[0] = 0
        self.free = (comp == int(np.argmax(sizes))) & (ok > 0) if n > 1 else ok > 0
        self._graph = None

    def nearest(self, xy: np.ndarray) -> np.ndarray:
        """The free cell centre nearest to ``xy``."""
        cand = self.xy[self.free]
        return cand[int(np.argmin(np.linalg.norm(cand - xy, axis=1)))]

    def walk(self, a: np.ndarray, b: np.ndarray) -> np.ndarray:
        """Points [n, 2] of a shortest walk over the free floor from ``a`` to ``b`` (both free), smoothed
        where the smoothing keeps a quarter of the clearance."""
        from scipy.sparse import coo_matrix
        from scipy.sparse.csgraph import dijkstra

        nx, ny = self.free.shape
        index = np.full(self.free.shape, -1, np.int64)
        cells = np.argwhere(self.free)
        index[tuple(cells.T)] = np.arange(len(cells))
        if self._graph is None:
            rows, cols, w = [], [], []
            for dx, dy in ((1, 0), (0, 1), (1, 1), (1, -1)):
                j = cells + [dx, dy]
                ok = (j[:, 0] >= 0) & (j[:, 0] < nx) & (j[:, 1] >= 0) & (j[:, 1] < ny)
                ok[ok] = self.free[j[ok, 0], j[ok, 1]]
                rows.append(np.nonzero(ok)[0])
                cols.append(index[j[ok, 0], j[ok, 1]])
                w.append(np.full(int(ok.sum()), np.hypot(dx, dy)))
            r, c, ww = np.concatenate(rows), np.concatenate(cols), np.concatenate(w)
            self._graph = coo_matrix(
                (np.r_[ww, ww], (np.r_[r, c], np.r_[c, r])), shape=(len(cells),) * 2
            ).tocsr()
        ia = index[self._cell(a)]
        ib = index[self._cell(b)]
        _, pred = dijkstra(self._graph, indices=ia, return_predecessors=True)
        chain = [ib]
        while chain[-1] != ia and pred[chain[-1]] >= 0:
            chain.append(int(pred[chain[-1]]))
        pts = np.concatenate([[a], self.xy[tuple(cells[chain[::-1]].T)][1:-1], [b]])
        dense = _resample(pts, 0.02)
        if len(dense) > 5:
            k = 15
            pad = np.concatenate([np.repeat(dense[:1], k, 0), dense, np.repeat(dense[-1:], k, 0)])
            smooth = np.stack(
                [np.convolve(pad[:, i], np.ones(2 * k + 1) / (2 * k + 1), "valid") for i in (0, 1)], 1
            )
            if np.all(self.clearance_at(smooth) >= 0.25):
                dense = smooth
        return dense

    def _cell(self, xy: np.ndarray) -> tuple[int, int]:
        i = int(np.clip((xy[0] + self.W / 2) / self.cell, 0, self.free.shape[0] - 1))
        j = int(np.clip((xy[1] + self.D / 2) / self.cell, 0, self.free.shape[1] - 1))
        return i, j

    def clearance_at(self, pts: np.ndarray) -> np.ndarray:
        i = np.clip(((pts[:, 0] + self.W / 2) / self.cell).astype(int), 0, self.free.shape[0] - 1)
        j = np.clip(((pts[:, 1] + self.D / 2) / self.cell).astype(int), 0, self.free.shape[1] - 1)
        return self.clearance[i, j]


def _resample(pts: np.ndarray, step: float) -> np.ndarray:
    """A polyline resampled every ``step`` metres (its ends kept)."""
    seg = np.linalg.norm(np.diff(pts, axis=0), axis=1)
    s = np.concatenate([[0.0], np.cumsum(seg)])
    if s[-1] <= 0:
        return pts[:1]
    t = np.linspace(0.0, s[-1], max(2, int(np.ceil(s[-1] / step)) + 1))
    return np.stack([np.interp(t, s, pts[:, i]) for i in range(pts.shape[1])], 1)


@dataclass
class _Stop:
    """Where the camera looks at one furniture group: from ``a`` to ``b`` (free floor) while its gaze pans
    from ``look_a`` to ``look_b`` (3D points on the group)."""

    a: np.ndarray
    b: np.ndarray
    look_a: np.ndarray
    look_b: np.ndarray


def _stops(room: Room, floor: _FreeFloor, rng: np.random.Generator) -> list[_Stop]:
    """One stop per group of large furniture (pieces within half a metre of each other), in the order of
    their direction from the room centre."""
    big = [o for o in room.zup_objects if o.class_name in LARGE_FURNITURE and o.support_relation == "on"]
    boxes = [o.aabb for o in big]
    sets = DisjointSets()
    for i in range(len(big)):
        for j in range(i + 1, len(big)):
            gap = np.maximum(
                np.maximum(boxes[i][0][:2] - boxes[j][1][:2], boxes[j][0][:2] - boxes[i][1][:2]), 0
            )
            if np.linalg.norm(gap) < 0.5:
                sets.union(i, j)
    groups: dict[int, list[int]] = {}
    for i in range(len(big)):
        groups.setdefault(sets.find(i), []).append(i)
    stops = []
    for members in groups.values():
        lo = np.min([boxes[i][0] for i in members], 0)
        hi = np.max([boxes[i][1] for i in members], 0)
        c = (lo + hi) / 2
        axis = int(np.argmax((hi - lo)[:2]))
        half = max(0.0, (hi - lo)[axis] / 2 - 0.25)
        ends = [c.copy(), c.copy()]
        ends[0][axis] -= half
        ends[1][axis] += half
        z = min(0.9, 0.6 * hi[2])
        for e in ends:
            e[2] = z
        # stand 1.6 to 2.6 m from the group's centre, on the room's side of it
        cand = floor.xy[floor.free]
        d = np.linalg.norm(cand - c[:2], axis=1)
        toward = (cand - c[:2]) @ (-c[:2] / max(np.linalg.norm(c[:2]), 1e-6))
        good = cand[(d > 1.6 + 0.3 * half) & (d < 2.6 + 0.5 * half) & (toward > 0.3)]
        if len(good) == 0:
            good = cand[np.argsort(np.abs(d - 2.0))[:10]]
        a = good[int(rng.integers(len(good)))]
        side = np.array([-(c[1] - a[1]), c[0] - a[0]])
        side /= max(np.linalg.norm(side), 1e-6)
        b = floor.nearest(a + side * rng.uniform(-0.7, 0.7))
        if rng.uniform() < 0.5:
            ends = ends[::-1]
        stops.append(_Stop(a, b, ends[0], ends[1]))
    angle = [np.arctan2(*((s.look_a + s.look_b)[1::-1] / 2)) for s in stops]
    return [stops[i] for i in np.argsort(angle)]


def _tour(n_stops: int, rng: np.random.Generator, length: int) -> list[int]:
    """The order of the stops: around the room once, stepping back to an earlier stop after every third new
    one, then stops at random (each a return), never the same stop twice in a row."""
    if n_stops == 1:
        return [0] * length
    start, direction = int(rng.integers(n_stops)), 1 if rng.uniform() < 0.5 else -1
    order: list[int] = []
    for k in range(n_stops):
        order.append((start + direction * k) % n_stops)
        if k % 3 == 2 and k + 1 < n_stops:
            order.append(order[int(rng.integers(max(1, len(order) - 3)))])
    while len(order) < length:
        nxt = int(rng.integers(n_stops))
        if nxt != order[-1]:
            order.append(nxt)
    return order


def _view_angles(xy: np.ndarray, height: float, target: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Yaw and pitch (radians) of a camera at ``xy`` [N, 2] and ``height`` looking at ``target`` [N, 3]."""
    d = target[:, :2] - xy
    return np.arctan2(d[:, 1], d[:, 0]), np.arctan2(target[:, 2] - height, np.linalg.norm(d, axis=1))


def _rotations_zup(yaw: np.ndarray, pitch: np.ndarray) -> np.ndarray:
    """Camera-to-world rotations [N, 3, 3] (OpenCV axes, z-up world) of a gaze, the pitch kept between 8 and
    55 degrees down."""
    pitch = np.clip(pitch, np.deg2rad(-55), np.deg2rad(-8))
    fwd = np.stack([np.cos(yaw) * np.cos(pitch), np.sin(yaw) * np.cos(pitch), np.sin(pitch)], -1)
    right = np.stack([np.sin(yaw), -np.cos(yaw), np.zeros_like(yaw)], -1)  # fwd x up, normalised
    down = np.cross(fwd, right)
    return np.stack([right, down, fwd], axis=-1)


def _rotation_deg(Ra: np.ndarray, Rb: np.ndarray) -> np.ndarray:
    """The angle between rotations (degrees), batched over the leading axis."""
    tr = np.einsum("...ij,...ij->...", Ra, Rb)
    return np.rad2deg(np.arccos(np.clip((tr - 1) / 2, -1.0, 1.0)))


def _leg(floor: _FreeFloor, a, b, look_a, look_b, height: float, pan: bool) -> tuple[np.ndarray, ...]:
    """Positions [n, 2], yaw and pitch [n] of one leg of the walk, from ``a`` looking at ``look_a`` to ``b``
    looking at ``look_b``, a sample every 2 cm and every degree. A pan (short, near the furniture group) looks
    at the points between the two; a walk between groups turns its gaze evenly from one to the other (a
    point between two groups can pass under the camera)."""
    xy = floor.walk(a, b) if np.linalg.norm(a - b) > 1e-6 else a[None]
    y0, p0 = _view_angles(a[None], height, look_a[None])
    y1, p1 = _view_angles(b[None], height, look_b[None])
    turn = float(np.arctan2(np.sin(y1 - y0), np.cos(y1 - y0))[0])
    n = max(len(xy), int(np.rad2deg(abs(turn))) + 2, 20 if pan else 2)
    if n > len(xy):
        s = np.linspace(0.0, len(xy) - 1, n)
        xy = np.stack([np.interp(s, np.arange(len(xy)), xy[:, k]) for k in (0, 1)], 1)
    t = np.linspace(0.0, 1.0, n)
    t = t * t * (3 - 2 * t)
    if pan:
        yaw, pitch = _view_angles(xy, height, (1 - t)[:, None] * look_a + t[:, None] * look_b)
    else:
        yaw, pitch = y0 + turn * t, p0 + (p1 - p0) * t
    return xy, yaw, pitch


def _dense_path(room: Room, seed: int, need: float) -> tuple[np.ndarray, np.ndarray]:
    """Camera positions [K, 3] and rotations [K, 3, 3] (z-up) along a tour of the stops (:func:`_leg`), at
    least ``need`` long in :func:`_motion` units."""
    rng = np.random.default_rng(np.random.SeedSequence([seed, 0x5CA77]))
    floor = _FreeFloor(room)
    if not floor.free.any():
        floor = _FreeFloor(room, clearance=0.25)
    stops = _stops(room, floor, rng)
    if not stops:
        c = floor.nearest(np.zeros(2))
        stops = [_Stop(c, c, np.array([room.size[0] / 2, 0, 0.8]), np.array([0, room.size[1] / 2, 0.8]))]
    height = rng.uniform(1.35, 1.6)
    legs: list[tuple[np.ndarray, ...]] = []
    order = _tour(len(stops), rng, 4 * len(stops) + 8)
    here, gaze = stops[order[0]].a, stops[order[0]].look_a
    total = 0.0
    for i in order * 8:  # more rounds for very long scans
        s = stops[i]
        legs.append(_leg(floor, here, s.a, gaze, s.look_a, height, pan=False))
        legs.append(_leg(floor, s.a, s.b, s.look_a, s.look_b, height, pan=True))
        here, gaze = s.b, s.look_b
        xy, yaw, pitch = (np.concatenate(x) for x in zip(*legs[-2:]))
        P = np.column_stack([xy, np.full(len(xy), height)])
        total += _motion(P, _rotations_zup(yaw, pitch)).sum()
        if total >= need:
            break
    xy, yaw, pitch = (np.concatenate(x) for x in zip(*legs))
    P = np.column_stack([xy, np.full(len(xy), height)])
    P[:, 2] += 0.06 * np.sin(np.linspace(0.0, 9.0 * np.pi, len(P)))  # the hand-held camera's height wobble
    return P, _rotations_zup(yaw, pitch)


def _motion(P: np.ndarray, R: np.ndarray) -> np.ndarray:
    """Per step of a path: metres walked plus degrees turned, MAX_JUMP_M per MAX_JUMP_DEG."""
    if len(P) < 2:
        return np.zeros(0)
    return (
        np.linalg.norm(np.diff(P, axis=0), axis=1) + _rotation_deg(R[:-1], R[1:]) * MAX_JUMP_M / MAX_JUMP_DEG
    )


def _pick_frames(P: np.ndarray, R: np.ndarray, frames: int, rng: np.random.Generator) -> np.ndarray | None:
    """Indices of ``frames`` samples of the path: small steps of ``step`` x U(0.5, 1.5) in :func:`_motion`
    units and, with JUMP_PROB, a jump of U(0.6, 2.4) units, cut back to at most MAX_JUMP_M metres and
    MAX_JUMP_DEG degrees. The small step is the largest that still fits the path; None if none does."""
    cum = np.concatenate([[0.0], np.cumsum(_motion(P, R))])
    jump = rng.uniform(size=frames) < JUMP_PROB
    jitter = rng.uniform(0.5, 1.5, frames)
    jump_len = rng.uniform(0.6, 2.4, frames)

    def walk(step: float) -> np.ndarray | None:
        idx = [0]
        for f in range(1, frames):
            i = idx[-1]
            j = int(np.searchsorted(cum, cum[i] + (jump_len[f] if jump[f] else step * jitter[f])))
            if j >= len(P):
                return None
            while (
                jump[f]
                and j > i + 1
                and (np.linalg.norm(P[j] - P[i]) > MAX_JUMP_M or _rotation_deg(R[i], R[j]) > MAX_JUMP_DEG)
            ):
                j -= 1
            idx.append(max(j, i + 1))
        return np.asarray(idx)

    lo, hi = 1e-4, SMALL_STEP * 4
    best = walk(lo)
    if best is None:
        return None
    for _ in range(30):
        mid = (lo + hi) / 2
        got = walk(mid)
        if got is None:
            hi = mid
        else:
            lo, best = mid, got
    return best


def scan_trajectory(room: Room, frames: int, seed: int) -> np.ndarray:
    """[frames, 4, 4] c2w poses (world frame) of a long scan of ``room`` (see the module docstring)."""
    rng = np.random.default_rng(np.random.SeedSequence([seed, 0x5CA78]))
    need = max(2.0, frames * (SMALL_STEP * (1 - JUMP_PROB) + JUMP_PROB * 1.6))
    idx = None
    for _ in range(6):  # a longer walk where the jumps took more of it than expected
        P, R = _dense_path(room, seed, need)
        idx = _pick_frames(P, R, frames, rng) if frames > 1 else np.zeros(1, np.int64)
        if idx is not None:
            break
        need *= 1.3
    if idx is None:  # a room with almost no free floor: every sample of the walk there is
        idx = np.minimum(np.arange(frames), len(P) - 1)
    poses = np.tile(np.eye(4), (frames, 1, 1))
    poses[:, :3, :3] = WORLD_FROM_ZUP @ R[idx]
    poses[:, :3, 3] = P[idx] @ WORLD_FROM_ZUP.T
    return poses


# --------------------------------------------------------------------------------------- first-view merges


def merge_partners(room: Room) -> dict[int, list[int]]:
    """{instance: what SAM may merge it with in its first views}: for an object standing on the floor, the
    floor and the large furniture standing next to it (footprints within :data:`ADJACENT_GAP`); for an
    object on a large piece of furniture, that piece."""
    objs = {o.instance_id: o for o in room.zup_objects}
    standing = [o for o in room.zup_objects if o.support is not None and o.support_relation == "on"
                and objs[o.support].class_name == "floor"]  # fmt: skip
    out: dict[int, list[int]] = {}
    for o in standing:
        lo, hi = o.aabb
        near = []
        for other in standing:
            if other is o or other.class_name not in LARGE_FURNITURE:
                continue
            olo, ohi = other.aabb
            gap = np.maximum(np.maximum(lo[:2] - ohi[:2], olo[:2] - hi[:2]), 0.0)
            if np.linalg.norm(gap) <= ADJACENT_GAP:
                near.append(other.instance_id)
        out[o.instance_id] = [o.support, *near]
    for o in room.zup_objects:
        if o.support in objs and objs[o.support].class_name in LARGE_FURNITURE and o.support_relation == "on":
            out[o.instance_id] = [o.support]
    return out


def plan_first_view_merges(
    partners: dict[int, list[int]], areas: np.ndarray, prob: float, seed: int
) -> dict[int, dict]:
    """Which objects SAM under-segments in their first views, with what, and in which frames.

    ``areas``: [frames, instances + 1] pixels of each instance per frame (a view shows an object from
    :data:`FIRST_VIEW_AREA` of the image on). Each object of ``partners`` is picked with ``prob`` (seeded);
    its partner is the floor (or its support) with probability 0.6, else a large piece of furniture next to
    it. Returns {instance: {"partner": id, "frames": [its first FIRST_VIEWS views]}}."""
    rng = np.random.default_rng(np.random.SeedSequence([seed, 0xF1257]))
    if areas.size == 0:
        return {}
    shown = areas >= FIRST_VIEW_AREA * areas.sum(axis=1, keepdims=True).clip(min=1)
    plan: dict[int, dict] = {}
    for inst in sorted(partners):
        pick, choice, which = rng.uniform(size=3)  # three draws each: one's plan never moves another's
        cand = partners[inst]
        if pick >= prob or inst >= areas.shape[1] or not cand:
            continue
        views = np.nonzero(shown[:, inst])[0][:FIRST_VIEWS]
        if views.size == 0:
            continue
        partner = cand[0] if choice < 0.6 or len(cand) == 1 else cand[1 + int(which * (len(cand) - 1))]
        plan[int(inst)] = {"partner": int(partner), "frames": [int(v) for v in views]}
    return plan


def merges_by_frame(plan: dict[int, dict]) -> dict[int, dict[int, int]]:
    """{frame: {instance: partner}} of a first-view plan (what the simulated SAM takes)."""
    out: dict[int, dict[int, int]] = {}
    for inst, p in plan.items():
        for f in p["frames"]:
            out.setdefault(int(f), {})[int(inst)] = int(p["partner"])
    return out
