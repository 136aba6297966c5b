"""``gaussians.ply``: the one reader and writer of a run's Gaussians as a 3DGS PLY (docs/formats.md
"gaussians.ply"): binary little-endian, SH degree 0 (the colour as ``f_dc_*``), log scales, opacity logits,
unit quaternions (``rot_*``, wxyz), and the ``label`` (int32) and ``confidence`` (float32) of each Gaussian.

Only numpy and plyfile: the viewer, ``eval`` and ``export`` read a run wherever the files are, without torch.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..atomic import atomic_path
from ..errors import DataError

SH_C0 = 0.28209479177387814

PLY_PROPERTIES: list[tuple[str, str]] = (
    [("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("nx", "<f4"), ("ny", "<f4"), ("nz", "<f4")]
    + [(f"f_dc_{i}", "<f4") for i in range(3)]
    + [("opacity", "<f4")]
    + [(f"scale_{i}", "<f4") for i in range(3)]
    + [(f"rot_{i}", "<f4") for i in range(4)]
    + [("label", "<i4"), ("confidence", "<f4")]
)
#: What a 3DGS renderer needs (the viewer, ``GaussianMap.read_ply``); ``eval`` needs only the centres and
#: the labels.
GAUSSIAN_FIELDS = ["x", "y", "z", "f_dc_0", "f_dc_1", "f_dc_2", "opacity"]
GAUSSIAN_FIELDS += [f"scale_{i}" for i in range(3)] + [f"rot_{i}" for i in range(4)]
SEMANTIC_FIELDS = ["x", "y", "z", "label"]


def write_gaussians_ply(
    path: str | Path,
    means: np.ndarray,
    colors: np.ndarray,
    log_scales: np.ndarray,
    opacity_logits: np.ndarray,
    quats: np.ndarray,
    labels: np.ndarray,
    confidences: np.ndarray,
) -> None:
    """Write ``path`` atomically. ``means`` [N,3], ``colors`` [N,3] RGB in [0, 1] (stored as SH degree 0),
    ``log_scales`` [N,3], ``opacity_logits`` [N], ``quats`` [N,4] wxyz (normalised by the caller),
    ``labels`` [N] (-1 = unlabelled), ``confidences`` [N]."""
    from plyfile import PlyData, PlyElement

    vert = np.zeros(len(means), dtype=np.dtype(PLY_PROPERTIES))
    vert["x"], vert["y"], vert["z"] = means[:, 0], means[:, 1], means[:, 2]
    dc = (colors - 0.5) / SH_C0
    for i in range(3):
        vert[f"f_dc_{i}"] = dc[:, i]
        vert[f"scale_{i}"] = log_scales[:, i]
    vert["opacity"] = opacity_logits
    for i in range(4):
        vert[f"rot_{i}"] = quats[:, i]
    vert["label"] = labels
    vert["confidence"] = confidences
    ply = PlyData([PlyElement.describe(vert, "vertex")], text=False, byte_order="<")
    with atomic_path(path) as tmp:
        ply.write(str(tmp))


@dataclass
class GaussianPly:
    """The vertex fields of a Gaussian PLY as stored (float32; a field the file lacks is None)."""

    path: Path
    means: np.ndarray  # [N, 3]
    f_dc: np.ndarray | None  # [N, 3] SH degree-0 coefficients
    log_scales: np.ndarray | None  # [N, 3]
    opacity_logits: np.ndarray | None  # [N]
    quats: np.ndarray | None  # [N, 4] wxyz, as stored
    labels: np.ndarray | None  # [N] int32, -1 = unlabelled
    confidences: np.ndarray | None  # [N]

    def __len__(self) -> int:
        return len(self.means)

    def colors(self) -> np.ndarray:
        """[N, 3] RGB in [0, 1] from the SH degree-0 coefficients."""
        return np.clip(self._need(self.f_dc, "f_dc_0") * SH_C0 + 0.5, 0.0, 1.0)

    def scales(self) -> np.ndarray:
        """[N, 3] float32: exp of the stored log scales."""
        with np.errstate(over="ignore"):
            return np.exp(self._need(self.log_scales, "scale_0").astype(np.float64)).astype(np.float32)

    def opacities(self) -> np.ndarray:
        """[N] float32 in (0, 1): the sigmoid of the stored logits (clipped to +-60, where float32's sigmoid
        is already 0 or 1, so that no exp overflows)."""
        logit = np.asarray(self._need(self.opacity_logits, "opacity"), dtype=np.float64)
        return (1.0 / (1.0 + np.exp(-np.clip(logit, -60, 60)))).astype(np.float32)

    def arrays(self) -> dict[str, np.ndarray]:
        """What a viewer or a point-cloud export draws: means [N,3], quats [N,4] wxyz, scales [N,3],
        opacities [N], colors [N,3] in [0,1], labels [N] int32 (-1 when the file has none), confidences [N]
        float32 (0 when none)."""
        n = len(self)
        return {
            "means": self.means,
            "quats": self._need(self.quats, "rot_0"),
            "scales": self.scales(),
            "opacities": self.opacities(),
            "colors": self.colors(),
            "labels": self.labels if self.labels is not None else np.full(n, -1, np.int32),
            "confidences": self.confidences if self.confidences is not None else np.zeros(n, np.float32),
        }

    def _need(self, field: np.ndarray | None, name: str) -> np.ndarray:
        if field is None:
            raise DataError(f"{self.path}: PLY vertex lacks the property {name!r}")
        return field


def read_gaussians_ply(path: str | Path, required: list[str] = GAUSSIAN_FIELDS) -> GaussianPly:
    """Read a Gaussian PLY (``gaussians.ply``, or any 3DGS PLY). ``required``: the vertex properties the
    caller needs (:data:`GAUSSIAN_FIELDS` for rendering, :data:`SEMANTIC_FIELDS` for scoring labels).

    Raises:
        DataError: the file is missing, unreadable or lacks a required property, its centres are not
            finite, its labels not whole numbers or its confidences not finite; the message names the file.
    """
    from plyfile import PlyData

    p = Path(path)
    if not p.is_file():
        raise DataError(f"{p}: Gaussian PLY file does not exist")
    try:
        v = PlyData.read(str(p))["vertex"].data
    except Exception as e:  # plyfile raises several unrelated exception types on corrupt input
        raise DataError(f"{p}: cannot read PLY ({type(e).__name__}: {e})") from e
    names = v.dtype.names or ()
    missing = [k for k in required if k not in names]
    if "label" in missing:
        raise DataError(f"{p}: vertex field 'label' missing: not a semantic Gaussian map")
    if missing:
        raise DataError(f"{p}: PLY vertex lacks the 3DGS properties {missing}")
    n = len(v)

    def cols(*keys: str) -> np.ndarray | None:
        if any(k not in names for k in keys):
            return None
        return np.stack([np.asarray(v[k], dtype=np.float32) for k in keys], axis=1).reshape(n, len(keys))

    means = cols("x", "y", "z")
    assert means is not None
    bad = ~np.isfinite(means).all(axis=1)
    if bad.any():
        raise DataError(f"{p}: {int(bad.sum())} vertices have NaN/inf coordinates")
    labels = None
    if "label" in names:
        raw = np.asarray(v["label"])
        if np.issubdtype(raw.dtype, np.floating) and not (np.isfinite(raw) & (raw == np.round(raw))).all():
            raise DataError(f"{p}: field 'label' must hold whole numbers")
        labels = raw.astype(np.int32)
    confidences = None
    if "confidence" in names:
        confidences = np.asarray(v["confidence"], dtype=np.float32)
        if not np.isfinite(confidences).all():
            raise DataError(f"{p}: field 'confidence' has NaN/inf")
    return GaussianPly(
        path=p,
        means=means,
        f_dc=cols("f_dc_0", "f_dc_1", "f_dc_2"),
        log_scales=cols("scale_0", "scale_1", "scale_2"),
        opacity_logits=np.asarray(v["opacity"], dtype=np.float32) if "opacity" in names else None,
        quats=cols("rot_0", "rot_1", "rot_2", "rot_3"),
        labels=labels,
        confidences=confidences,
    )


__all__ = [
    "GAUSSIAN_FIELDS",
    "GaussianPly",
    "PLY_PROPERTIES",
    "SEMANTIC_FIELDS",
    "SH_C0",
    "read_gaussians_ply",
    "write_gaussians_ply",
]
