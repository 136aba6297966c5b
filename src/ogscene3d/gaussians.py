"""GaussianMap: the semantic 3D Gaussian map as struct-of-arrays torch tensors on one device.

Each Gaussian i has a centre ``means[i]`` (metres, world frame), a rotation ``quats[i]`` (wxyz, not
necessarily normalised; the renderer normalises), ``log_scales[i]`` (the renderer takes ``exp``),
an opacity logit (the renderer takes ``sigmoid``), a plain RGB colour in [0, 1] (no SH), a scene label
(int32, -1 = unlabeled), a semantic confidence in [0, 1] and the index of the keyframe that created it.

Storage grows with amortised capacity: the backing tensors are over-allocated (doubling) so appending
a keyframe's Gaussians is O(new) and never reallocates on every call. All public accessors return views
of the first ``len(map)`` rows. ``next_label`` is the next unused scene label (labels are never reused).

Files: ``save_npz``/``load_npz`` hold everything needed to resume mapping; ``export_ply`` writes the
3DGS vertex layout at SH degree 0 plus ``label`` and ``confidence`` (README "File formats").
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import torch

from .device import resolve_device
from .errors import DataError
from .runs.gaussians_ply import PLY_PROPERTIES, SH_C0, read_gaussians_ply, write_gaussians_ply
from .runs.map_npz import NPZ_VERSION, pop_npz_version, read_map_npz, write_map_npz

# Per-Gaussian fields: name -> (trailing shape, dtype).
FIELDS: dict[str, tuple[tuple[int, ...], torch.dtype]] = {
    "means": ((3,), torch.float32),
    "quats": ((4,), torch.float32),
    "log_scales": ((3,), torch.float32),
    "opacity_logits": ((), torch.float32),
    "colors": ((3,), torch.float32),
    "labels": ((), torch.int32),
    "confidences": ((), torch.float32),
    "origin_kf": ((), torch.int32),
}
_FLOAT_FIELDS = [k for k, (_, dt) in FIELDS.items() if dt.is_floating_point]


def _logit(p: torch.Tensor | float) -> torch.Tensor:
    p = torch.as_tensor(p, dtype=torch.float32).clamp(1e-6, 1 - 1e-6)
    return torch.log(p) - torch.log1p(-p)


class _FieldView:
    """A read-only ``GaussianMap`` attribute: the first ``len(map)`` rows of the field of its name (a view,
    so in-place writes reach the map; assigning the attribute raises, as a property without setter does)."""

    def __init__(self, doc: str) -> None:
        self.__doc__ = doc

    def __set_name__(self, owner: type, name: str) -> None:
        if name not in FIELDS:
            raise TypeError(f"{owner.__name__}.{name}: not a Gaussian field (known: {sorted(FIELDS)})")
        self.name = name

    def __get__(self, gm: GaussianMap | None, owner: type | None = None) -> torch.Tensor:
        if gm is None:
            return self  # type: ignore[return-value]  # the class attribute (documentation, introspection)
        return gm._view(self.name)

    def __set__(self, gm: GaussianMap, value: object) -> None:
        raise AttributeError(f"can't set attribute {self.name!r} (write into the view instead)")


class GaussianMap:
    """Struct-of-arrays semantic Gaussians on ``device`` with amortised-capacity growth.

    Each field (``means``, ``quats``, ``log_scales``, ``opacity_logits``, ``colors``, ``labels``,
    ``confidences``, ``origin_kf``) is a view of the first ``len(map)`` rows of its storage.

    Args:
        device: "cpu", "cuda", "cuda:N", a torch.device, or None (CUDA when available).
        capacity: rows allocated up front (the storage doubles as rows are appended).
    """

    def __init__(self, device: str | torch.device = "cpu", capacity: int = 1024) -> None:
        self.device = resolve_device(device)
        self._n = 0
        self.next_label = 0
        cap = max(int(capacity), 1)
        self._data: dict[str, torch.Tensor] = {
            k: torch.zeros((cap, *shape), dtype=dt, device=self.device) for k, (shape, dt) in FIELDS.items()
        }
        # auxiliary per-Gaussian float values (mapping/evidence.py), not saved: name -> value of new rows
        self._aux: dict[str, float] = {}

    # ------------------------------------------------------------------ access
    def __len__(self) -> int:
        return self._n

    @property
    def capacity(self) -> int:
        return int(self._data["means"].shape[0])

    def _view(self, name: str) -> torch.Tensor:
        return self._data[name][: self._n]

    means = _FieldView("[N, 3] float32 world-frame centres (metres).")
    quats = _FieldView("[N, 4] float32 rotations, wxyz.")
    log_scales = _FieldView("[N, 3] float32 log of the per-axis standard deviations (metres).")
    opacity_logits = _FieldView("[N] float32 opacity logits.")
    colors = _FieldView("[N, 3] float32 RGB in [0, 1].")
    labels = _FieldView("[N] int32 scene labels, -1 = unlabeled.")
    confidences = _FieldView("[N] float32 semantic confidences in [0, 1].")
    origin_kf = _FieldView("[N] int32 index of the keyframe that created each Gaussian.")

    @property
    def scales(self) -> torch.Tensor:
        """[N, 3] activated scales (``exp(log_scales)``)."""
        return self.log_scales.exp()

    @property
    def opacities(self) -> torch.Tensor:
        """[N] activated opacities (``sigmoid(opacity_logits)``)."""
        return torch.sigmoid(self.opacity_logits)

    def field(self, name: str) -> torch.Tensor:
        if name not in FIELDS:
            raise KeyError(f"unknown Gaussian field {name!r}; known: {sorted(FIELDS)}")
        return self._view(name)

    def aux(self, name: str, fill: float = 0.0) -> torch.Tensor:
        """[N] float32 auxiliary per-Gaussian values that follow appends, pruning and growth like the fields
        (new Gaussians start at ``fill``), created on first use; not written to files."""
        if name in FIELDS:
            raise KeyError(f"{name!r} is a Gaussian field, not an auxiliary value")
        if name not in self._data:
            self._data[name] = torch.full((self.capacity,), float(fill), device=self.device)
            self._aux[name] = float(fill)
        return self._view(name)

    def new_labels(self, count: int) -> torch.Tensor:
        """Reserve ``count`` fresh scene labels (int32 tensor on the map's device)."""
        start = self.next_label
        self.next_label += int(count)
        return torch.arange(start, start + int(count), dtype=torch.int32, device=self.device)

    # ------------------------------------------------------------------ growth
    def _reserve(self, total: int) -> None:
        cap = self.capacity
        if total <= cap:
            return
        new_cap = max(total, 2 * cap)
        for k, t in self._data.items():
            grown = torch.zeros((new_cap, *t.shape[1:]), dtype=t.dtype, device=self.device)
            grown[: self._n] = t[: self._n]
            self._data[k] = grown

    def append(
        self,
        means: torch.Tensor,
        colors: torch.Tensor,
        log_scales: torch.Tensor,
        labels: torch.Tensor | None = None,
        confidences: torch.Tensor | None = None,
        quats: torch.Tensor | None = None,
        opacity_logits: torch.Tensor | None = None,
        origin_kf: int | torch.Tensor = 0,
    ) -> slice:
        """Append M Gaussians; returns the slice of their rows.

        means [M,3], colors [M,3] in [0,1], log_scales [M,3] or [M] (isotropic), labels [M] int (default -1),
        confidences [M] (default 0), quats [M,4] wxyz (default identity), opacity_logits [M] (default
        logit(0.5)). Non-finite values are rejected.
        """
        means = torch.as_tensor(means, dtype=torch.float32, device=self.device)
        if means.ndim != 2 or means.shape[1] != 3:
            raise ValueError(f"append: means must be [M, 3], got {tuple(means.shape)}")
        m = means.shape[0]

        def prep(x, name: str, default) -> torch.Tensor:
            shape, dt = FIELDS[name]
            if x is None:
                x = default
            x = torch.as_tensor(x, device=self.device)
            if x.ndim == 0:
                x = x.expand(m, *shape)
            elif name == "log_scales" and x.ndim == 1 and x.shape[0] == m:
                x = x[:, None].expand(m, 3)  # isotropic
            if name == "labels" and x.numel() and not x.dtype.is_floating_point:
                lo, hi = torch.iinfo(torch.int32).min, torch.iinfo(torch.int32).max
                if int(x.min()) < lo or int(x.max()) > hi:
                    raise ValueError("append: labels must fit in int32 (-1 = unlabelled)")
            x = x.to(dt)
            if tuple(x.shape) != (m, *shape):
                raise ValueError(f"append: {name} must have shape {(m, *shape)}, got {tuple(x.shape)}")
            if dt.is_floating_point and not bool(torch.isfinite(x).all()):
                raise ValueError(f"append: {name} contains NaN or inf")
            if name == "confidences" and x.numel() and not bool(((x >= 0) & (x <= 1)).all()):
                raise ValueError("append: confidences must lie in [0, 1]")
            return x

        identity = torch.tensor([1.0, 0.0, 0.0, 0.0], device=self.device)
        rows = {
            "means": prep(means, "means", None),
            "colors": prep(colors, "colors", None),
            "log_scales": prep(log_scales, "log_scales", None),
            "labels": prep(labels, "labels", -1),
            "confidences": prep(confidences, "confidences", 0.0),
            "quats": prep(quats, "quats", identity.expand(m, 4)),
            "opacity_logits": prep(opacity_logits, "opacity_logits", 0.0),
            "origin_kf": prep(origin_kf, "origin_kf", 0),
        }
        if m and int(rows["labels"].max()) >= self.next_label:
            self.next_label = int(rows["labels"].max()) + 1
        start = self._n
        self._reserve(start + m)
        for k, v in rows.items():
            self._data[k][start : start + m] = v
        for k, fill in self._aux.items():
            self._data[k][start : start + m] = fill
        self._n = start + m
        return slice(start, start + m)

    def keep(self, mask: torch.Tensor) -> None:
        """Keep the Gaussians where ``mask`` [N] bool is True (order preserved, capacity unchanged)."""
        mask = torch.as_tensor(mask, device=self.device)
        if mask.dtype != torch.bool or mask.shape != (self._n,):
            raise ValueError(f"keep: mask must be bool [{self._n}], got {mask.dtype} {tuple(mask.shape)}")
        idx = torch.nonzero(mask).squeeze(1)
        m = int(idx.numel())
        for t in self._data.values():
            t[:m] = t[idx]
        self._n = m

    def prune(self, min_opacity: float, max_scale: float) -> int:
        """Remove transparent (opacity < min_opacity) or oversized (max scale > max_scale m; 0 = off)
        Gaussians and any with non-finite parameters. Returns how many were removed."""
        if self._n == 0:
            return 0
        bad = self.opacities < min_opacity
        if max_scale > 0:
            bad |= self.log_scales.max(dim=1).values > math.log(max_scale)
        for k in _FLOAT_FIELDS:
            v = self._view(k)
            bad |= ~torch.isfinite(v.reshape(self._n, -1)).all(dim=1)
        removed = int(bad.sum())
        if removed:
            self.keep(~bad)
        return removed

    def to(self, device: str | torch.device) -> GaussianMap:
        out = GaussianMap(device, capacity=max(self._n, 1))
        for k in FIELDS:
            out._data[k][: self._n] = self._view(k).to(out.device)
        out._n = self._n
        out.next_label = self.next_label
        return out

    def memory_bytes(self) -> int:
        """Bytes held by the backing tensors (capacity, not just the used rows)."""
        return sum(t.numel() * t.element_size() for t in self._data.values())

    # ------------------------------------------------------------------ files
    def state_dict(self) -> dict[str, np.ndarray]:
        out = {k: self._view(k).detach().cpu().numpy() for k in FIELDS}
        out["next_label"] = np.array(self.next_label, dtype=np.int64)
        out["version"] = np.array(NPZ_VERSION, dtype=np.int64)
        return out

    @classmethod
    def from_state_dict(
        cls, state: dict[str, np.ndarray], device: str | torch.device = "cpu", what: str = "state"
    ) -> GaussianMap:
        missing = [k for k in FIELDS if k not in state]
        if missing:
            raise DataError(f"{what}: missing Gaussian fields {missing}")
        n = int(np.asarray(state["means"]).shape[0])
        gm = cls(device, capacity=max(n, 1))
        for k, (shape, dt) in FIELDS.items():
            arr = np.asarray(state[k])
            if arr.shape != (n, *shape):
                raise DataError(f"{what}: field {k!r} has shape {arr.shape}, expected {(n, *shape)}")
            t = torch.from_numpy(np.ascontiguousarray(arr)).to(dtype=dt)
            if dt.is_floating_point and not bool(torch.isfinite(t).all()):
                raise DataError(f"{what}: field {k!r} contains NaN or inf")
            gm._data[k][:n] = t.to(gm.device)
        gm._n = n
        labels_max = int(gm.labels.max()) + 1 if n else 0
        gm.next_label = max(int(state.get("next_label", labels_max)), labels_max)
        return gm

    def save_npz(self, path: str | Path, extra: dict[str, np.ndarray] | None = None) -> None:
        """Write the map to an npz file (``map.npz``'s format), atomically.

        Args:
            path: the file to write.
            extra: more named arrays to store beside the map's (e.g. a mapper's state); a name may not
                clash with a map field.
        """
        arrays = self.state_dict()
        for k, v in (extra or {}).items():
            if k in arrays:
                raise ValueError(f"save_npz: extra key {k!r} clashes with a map field")
            arrays[k] = np.asarray(v)
        write_map_npz(path, arrays)

    @classmethod
    def load_npz(cls, path: str | Path, device: str | torch.device = "cpu") -> GaussianMap:
        """Load a map written by :meth:`save_npz` (its extra arrays are left out: read them with ``np.load``).

        Args:
            path: the npz file.
            device: where the map's tensors go.

        Returns:
            The map.

        Raises:
            DataError: the file is missing, damaged, lacks a field, or was written by a newer ogscene3d.
        """
        p = Path(path)
        # only the map's arrays: a mapper checkpoint also holds its memory views (hundreds of MB)
        state = read_map_npz(p, lambda k: k in FIELDS or k in ("next_label", "version"))
        pop_npz_version(state, p, "map", "read it")
        return cls.from_state_dict(state, device, what=str(p))

    def export_ply(self, path: str | Path) -> None:
        """Write the 3DGS PLY that other Gaussian splatting tools open (``ogscene3d.runs.gaussians_ply``).

        Binary little-endian, SH degree 0, plus the properties ``label`` (int32) and ``confidence``
        (float32).

        Args:
            path: the ``.ply`` file to write.
        """
        write_gaussians_ply(
            path,
            means=self.means.detach().cpu().numpy(),
            colors=self.colors.detach().cpu().numpy(),
            log_scales=self.log_scales.detach().cpu().numpy(),
            opacity_logits=self.opacity_logits.detach().cpu().numpy(),
            quats=torch.nn.functional.normalize(self.quats.detach(), dim=1).cpu().numpy(),
            labels=self.labels.cpu().numpy(),
            confidences=self.confidences.detach().cpu().numpy(),
        )

    @classmethod
    def read_ply(cls, path: str | Path, device: str | torch.device = "cpu") -> GaussianMap:
        """Read a PLY written by :meth:`export_ply`, or any 3DGS PLY.

        Args:
            path: the ``.ply`` file.
            device: where the map's tensors go.

        Returns:
            The map; Gaussians without a label / confidence property get -1 / 0.
        """
        ply = read_gaussians_ply(path)
        n = len(ply)
        state = {
            "means": ply.means,
            "colors": ply.colors(),
            "log_scales": ply.log_scales,
            "quats": ply.quats,
            "opacity_logits": ply.opacity_logits,
            "labels": ply.labels if ply.labels is not None else np.full(n, -1, np.int32),
            "confidences": ply.confidences if ply.confidences is not None else np.zeros(n, np.float32),
            "origin_kf": np.zeros(n, np.int32),
        }
        return cls.from_state_dict(state, device, what=str(ply.path))


__all__ = ["GaussianMap", "FIELDS", "SH_C0", "PLY_PROPERTIES"]
