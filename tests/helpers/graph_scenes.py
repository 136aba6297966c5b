"""Hand-built indoor scenes for the scene-graph tests: furniture as point samples on box surfaces.

Scenes are built in a z-up frame (metres) and rotated so that z maps onto the requested world up vector,
so the same scene can be tested with the project's default up axis [0, -1, 0] and with others.
"""

from __future__ import annotations

import numpy as np


def rotation_to_up(up) -> np.ndarray:
    """A rotation R with R @ [0, 0, 1] = unit(up)."""
    u = np.asarray(up, dtype=np.float64)
    u = u / np.linalg.norm(u)
    z = np.array([0.0, 0.0, 1.0])
    v = np.cross(z, u)
    c = float(z @ u)
    if np.linalg.norm(v) < 1e-12:
        return np.eye(3) if c > 0 else np.diag([1.0, -1.0, -1.0])
    vx = np.array([[0, -v[2], v[1]], [v[2], 0, -v[0]], [-v[1], v[0], 0]])
    return np.eye(3) + vx + vx @ vx * (1.0 / (1.0 + c))


def box_surface(lo, hi, rng: np.random.Generator, density: float = 4000.0) -> np.ndarray:
    """Points sampled uniformly on the surface of the axis-aligned box [lo, hi] (z-up frame)."""
    lo, hi = np.asarray(lo, float), np.asarray(hi, float)
    d = hi - lo
    faces = []
    for axis in range(3):
        a, b = [k for k in range(3) if k != axis]
        area = d[a] * d[b]
        n = max(4, int(area * density))
        for side in (lo[axis], hi[axis]):
            p = np.empty((n, 3))
            p[:, axis] = side
            p[:, a] = rng.uniform(lo[a], hi[a], n)
            p[:, b] = rng.uniform(lo[b], hi[b], n)
            faces.append(p)
    return np.concatenate(faces)


def plane(lo, hi, rng: np.random.Generator, density: float = 1500.0) -> np.ndarray:
    """Points on a flat rectangle: ``lo``/``hi`` equal along exactly one axis (z-up frame)."""
    lo, hi = np.asarray(lo, float), np.asarray(hi, float)
    d = hi - lo
    area = np.prod([x for x in d if x > 0])
    n = max(10, int(area * density))
    return rng.uniform(lo, hi, (n, 3))


def table(rng, x0=0.0, y0=0.0, w=1.2, d=0.8, h=0.75, top=0.03) -> np.ndarray:
    parts = [box_surface([x0, y0, h - top], [x0 + w, y0 + d, h], rng)]
    for lx, ly in ((x0, y0), (x0 + w - 0.05, y0), (x0, y0 + d - 0.05), (x0 + w - 0.05, y0 + d - 0.05)):
        parts.append(box_surface([lx, ly, 0.0], [lx + 0.05, ly + 0.05, h - top], rng))
    return np.concatenate(parts)


def shelf(rng, x0=0.0, y0=0.0, w=0.8, d=0.3, h=0.84, t=0.02) -> np.ndarray:
    boards = [
        ([x0, y0, 0.0], [x0 + w, y0 + d, t]),  # bottom
        ([x0, y0, 0.4], [x0 + w, y0 + d, 0.4 + t]),  # middle
        ([x0, y0, h - t], [x0 + w, y0 + d, h]),  # top
        ([x0, y0, 0.0], [x0 + t, y0 + d, h]),  # sides
        ([x0 + w - t, y0, 0.0], [x0 + w, y0 + d, h]),
        ([x0, y0 + d - t, 0.0], [x0 + w, y0 + d, h]),  # back
    ]
    return np.concatenate([box_surface(lo, hi, rng) for lo, hi in boards])


def to_world(points: np.ndarray, up) -> np.ndarray:
    return points @ rotation_to_up(up).T


def walls_with_doors(x0, x1, y0, y1, H, rng, doors=(), t=0.05, density=300.0):
    """The inner faces of a rectangular room's four walls (z-up), with doorways ``doors`` = [(side, centre
    along the wall)] 0.9 m wide and 2.05 m high left open."""
    out = []
    for side in ("-x", "+x", "-y", "+y"):
        fixed = {"-x": x0, "+x": x1, "-y": y0, "+y": y1}[side]
        a0, a1 = (y0, y1) if side in ("-x", "+x") else (x0, x1)
        cuts = sorted(c for s, c in doors if s == side)
        pieces, start = [], a0
        for c in cuts:
            pieces.append((start, c - 0.45, 0.0, H))
            pieces.append((c - 0.45, c + 0.45, 2.05, H))
            start = c + 0.45
        pieces.append((start, a1, 0.0, H))
        for lo, hi, z0, z1 in pieces:
            if hi - lo < 1e-6:
                continue
            if side in ("-x", "+x"):
                out.append(plane([fixed, lo, z0], [fixed, hi, z1], rng, density))
            else:
                out.append(plane([lo, fixed, z0], [hi, fixed, z1], rng, density))
    return np.concatenate(out)


def blob_map(labels_present, n_per=400, seed=0):
    """Gaussian means: label k is a 0.3 m cube of points at x = 0.3 k (touching)."""
    rng = np.random.default_rng(seed)
    means, labels = [], []
    for k in labels_present:
        means.append(rng.uniform(0, 0.3, (n_per, 3)) + np.array([0.3 * k, 0.0, 0.0]))
        labels.append(np.full(n_per, k, np.int32))
    means = np.concatenate(means)
    labels = np.concatenate(labels)
    conf = np.full(len(means), 0.8, np.float32)
    colors = np.tile(np.array([[0.8, 0.1, 0.1]]), (len(means), 1))
    return means, labels, conf, colors
