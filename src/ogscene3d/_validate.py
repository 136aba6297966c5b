"""Argument checks shared by the public rendering functions: every message names the argument."""

from __future__ import annotations

import torch


class ValueChecks:
    """Checks on the values of device tensors, settled together with one host sync.

    Each ``bool(tensor)`` check stalls the CPU until the GPU has caught up, and a render call would make a
    dozen of them. Checks are recorded in order; ``settle`` raises the first one that failed, and can carry
    integers the caller needs on the host anyway (the rasterizer's intersection count) on the same sync.
    """

    def __init__(self) -> None:
        self._order: list[tuple[bool, str]] = []  # (is an extrema check, message)
        self._extrema: list[torch.Tensor] = []  # [min, max] per tensor: NaN or inf shows in one of them
        self._bad: list[torch.Tensor] = []

    def fail_if(self, bad: torch.Tensor, message: str) -> None:
        """``bad``: a one-element bool tensor, True when the check fails."""
        self._order.append((False, message))
        self._bad.append(bad.reshape(1))

    def finite(self, name: str, t: torch.Tensor) -> None:
        if t.is_floating_point() and t.numel():
            lo, hi = torch.aminmax(t)  # one reduction; NaN propagates, inf is an extreme
            self._order.append((True, f"{name} contains NaN or inf"))
            self._extrema.append(torch.stack([lo, hi]))

    def settle(self, extra: torch.Tensor | None = None) -> list[int]:
        """Raise the first failed check; return ``extra`` (an int tensor, any shape) as a list."""
        order, extrema, bad = self._order, self._extrema, self._bad
        self._order, self._extrema, self._bad = [], [], []
        parts = []
        if extrema:
            parts.append((~torch.isfinite(torch.stack(extrema))).any(dim=1))
        if bad:
            parts.append(torch.cat(bad))
        if extra is not None:
            parts.append(extra.reshape(-1))
        if not parts:
            return []
        dev = parts[0].device
        values = torch.cat([p.to(dev, torch.int64) for p in parts]).tolist()  # the one sync
        finite_failed = iter(values[: len(extrema)])
        other_failed = iter(values[len(extrema) : len(extrema) + len(bad)])
        for is_extrema, message in order:
            if next(finite_failed if is_extrema else other_failed):
                raise ValueError(message)
        return values[len(extrema) + len(bad) :]


def check_tensor(
    name: str,
    t: object,
    shape: tuple[int | None, ...],
    device: torch.device | None = None,
    dtypes: tuple[torch.dtype, ...] = (torch.float32,),
    finite: bool = True,
    checks: ValueChecks | None = None,
) -> torch.Tensor:
    """``shape`` entries of None accept any size. Returns the tensor (unchanged). With ``checks`` the NaN/inf
    test is recorded there instead of settled here."""
    if not isinstance(t, torch.Tensor):
        raise ValueError(f"{name} must be a torch.Tensor, got {type(t).__name__}")
    if t.dim() != len(shape) or any(s is not None and s != d for s, d in zip(shape, t.shape)):
        want = "[" + ", ".join("*" if s is None else str(s) for s in shape) + "]"
        raise ValueError(f"{name} must have shape {want}, got {list(t.shape)}")
    if t.dtype not in dtypes:
        raise ValueError(f"{name} must have dtype {' or '.join(str(d) for d in dtypes)}, got {t.dtype}")
    if device is not None and t.device != device:
        raise ValueError(f"{name} is on {t.device} but the other inputs are on {device}")
    if finite:
        own = checks if checks is not None else ValueChecks()
        own.finite(name, t)
        if checks is None:
            own.settle()
    return t


def check_image_size(width: object, height: object) -> tuple[int, int]:
    for name, v in (("width", width), ("height", height)):
        if isinstance(v, bool) or not isinstance(v, int) or v <= 0:
            raise ValueError(f"{name} must be a positive int, got {v!r}")
    return int(width), int(height)  # type: ignore[arg-type]
