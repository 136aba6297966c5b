"""Argument checks shared by the public rendering functions: every message names the argument."""

from __future__ import annotations

import torch


def check_tensor(
    name: str,
    t: object,
    shape: tuple[int | None, ...],
    device: torch.device | None = None,
    dtypes: tuple[torch.dtype, ...] = (torch.float32,),
    finite: bool = True,
) -> torch.Tensor:
    """``shape`` entries of None accept any size. Returns the tensor (unchanged)."""
    if not isinstance(t, torch.Tensor):
        raise ValueError(f"{name} must be a torch.Tensor, got {type(t).__name__}")
    if t.dim() != len(shape) or any(s is not None and s != d for s, d in zip(shape, t.shape)):
        want = "[" + ", ".join("*" if s is None else str(s) for s in shape) + "]"
        raise ValueError(f"{name} must have shape {want}, got {list(t.shape)}")
    if t.dtype not in dtypes:
        raise ValueError(f"{name} must have dtype {' or '.join(str(d) for d in dtypes)}, got {t.dtype}")
    if device is not None and t.device != device:
        raise ValueError(f"{name} is on {t.device} but the other inputs are on {device}")
    if finite and t.is_floating_point() and t.numel() and not bool(torch.isfinite(t).all()):
        raise ValueError(f"{name} contains NaN or inf")
    return t


def check_image_size(width: object, height: object) -> tuple[int, int]:
    for name, v in (("width", width), ("height", height)):
        if isinstance(v, bool) or not isinstance(v, int) or v <= 0:
            raise ValueError(f"{name} must be a positive int, got {v!r}")
    return int(width), int(height)  # type: ignore[arg-type]
