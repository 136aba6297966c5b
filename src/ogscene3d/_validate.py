"""Argument checks shared by the public rendering functions: every message names the argument."""

from __future__ import annotations

import numbers

import numpy as np
import torch


class ValueChecks:
    """Checks on the values of device tensors, settled together with one host sync.

    Each ``bool(tensor)`` check stalls the CPU until the GPU has caught up. Checks are recorded in order;
    ``settle`` raises the first one that failed, and can carry integers the caller needs on the host
    anyway (the rasterizer's intersection count) on the same sync.
    """

    def __init__(self) -> None:
        self._flags: list[torch.Tensor] = []
        self._messages: list[str] = []

    def fail_if(self, bad: torch.Tensor, message: str) -> None:
        """``bad``: a one-element bool tensor, True when the check fails."""
        self.fail_if_flags(bad.reshape(1), [message])

    def fail_if_flags(self, flags: torch.Tensor, messages: list[str]) -> None:
        """``flags`` [k] (nonzero = failed) with one message each, reported in this order."""
        if flags.numel() != len(messages):
            raise ValueError(f"{flags.numel()} flags but {len(messages)} messages")
        self._flags.append(flags.reshape(-1))
        self._messages.extend(messages)

    def settle(self, extra: torch.Tensor | None = None) -> list[int]:
        """Raise the first failed check; return ``extra`` (an int tensor, any shape) as a list."""
        flags, messages = self._flags, self._messages
        self._flags, self._messages = [], []
        parts = flags + ([extra.reshape(-1)] if extra is not None else [])
        if not parts:
            return []
        dev = parts[0].device
        values = torch.cat([p.to(dev, torch.int64) for p in parts]).tolist()  # the one sync
        for failed, message in zip(values, messages):
            if failed:
                raise ValueError(message)
        return values[len(messages) :]


def check_tensor(
    name: str,
    t: object,
    shape: tuple[int | None, ...],
    device: torch.device | None = None,
    dtypes: tuple[torch.dtype, ...] = (torch.float32,),
    finite: bool = True,
) -> torch.Tensor:
    """``shape`` entries of None accept any size. Returns the tensor (unchanged). ``finite=False`` leaves the
    NaN/inf test to the caller (the renderers test all their inputs in one kernel)."""
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


def check_int(name: str, v: object, lo: int, hi: int | None = None) -> int:
    """``v`` as an int in [lo, hi]: any integer type (Python's, numpy's, a 0-dim integer tensor), not bool."""
    if isinstance(v, torch.Tensor) and v.dim() == 0 and not v.is_floating_point() and v.dtype != torch.bool:
        v = int(v)
    if isinstance(v, (bool, np.bool_)) or not isinstance(v, numbers.Integral):
        ok = False
    else:
        v = int(v)
        ok = v >= lo and (hi is None or v <= hi)
    if not ok:
        what = f"an int >= {lo}" if hi is None else f"an int in [{lo}, {hi}]"
        raise ValueError(f"{name} must be {what}, got {v!r}")
    return v  # type: ignore[return-value]


def check_image_size(width: object, height: object) -> tuple[int, int]:
    return check_int("width", width, 1), check_int("height", height, 1)
