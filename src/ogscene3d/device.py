"""One place that turns a user's ``device=`` argument into torch and Warp devices."""

from __future__ import annotations

import contextlib
import functools
import os
import sys
import tempfile
from collections.abc import Iterator

import torch

from .errors import ConfigError


def resolve_device(device: str | torch.device | None = None) -> torch.device:
    """Accept "cpu", "cuda", "cuda:0", a torch.device or None (CUDA when available, else CPU)."""
    if device is None:
        return torch.device("cuda:0" if torch.cuda.is_available() else "cpu")
    try:
        dev = torch.device(device)
    except (RuntimeError, TypeError):
        dev = None
    if dev is None or dev.type not in ("cpu", "cuda"):
        raise ConfigError(f"device={device!r} is not supported: use 'cpu', 'cuda' or 'cuda:N'")
    if dev.type == "cuda":
        if not torch.cuda.is_available():
            raise ConfigError(f"device={device!r} was asked for but torch sees no CUDA GPU; use device='cpu'")
        if dev.index is None:
            dev = torch.device("cuda", torch.cuda.current_device())
        elif dev.index >= torch.cuda.device_count():
            raise ConfigError(f"device={device!r}: torch sees {torch.cuda.device_count()} CUDA GPU(s)")
    return dev


@functools.cache
def init_warp():
    """Initialise Warp once and return the module. Warp logs a line per module load; keep the console for
    our own progress (users can lower the log level again)."""
    import warp as wp

    if hasattr(wp, "LOG_WARNING"):
        wp.config.log_level = wp.LOG_WARNING
    else:
        wp.config.quiet = True
    with _without_driver_warning():
        wp.init()
    return wp


# What Warp's native library prints (C stdio, past Python's logging and warnings) on every start without a
# driver: on a CPU-only machine that is the expected state, not something to warn about. Asking for a CUDA
# device without one is still a clear error (resolve_device, warp_device).
NO_DRIVER_WARNING = "Could not find or load the NVIDIA CUDA driver"


@contextlib.contextmanager
def _without_driver_warning() -> Iterator[None]:
    """Capture file descriptor 2 while Warp starts and pass on everything but :data:`NO_DRIVER_WARNING`."""
    fd = 2  # the C side writes to descriptor 2, whatever sys.stderr has been replaced by
    sys.stderr.flush()
    with tempfile.TemporaryFile() as tmp:
        saved = os.dup(fd)
        os.dup2(tmp.fileno(), fd)
        try:
            yield
        finally:
            os.dup2(saved, fd)
            os.close(saved)
            tmp.seek(0)
            text = tmp.read().decode(errors="replace")
            kept = "".join(line for line in text.splitlines(True) if NO_DRIVER_WARNING not in line)
            if kept:
                sys.stderr.write(kept)
                sys.stderr.flush()


def warp_device(device: torch.device):
    """The Warp device for a torch device (initialises Warp on first use).

    Raises:
        ConfigError: a CUDA device is asked for and Warp cannot use CUDA (no driver, or a CPU-only Warp).
    """
    wp = init_warp()
    if device.type == "cuda" and not wp.is_cuda_available():
        raise ConfigError(
            f"device {device} was asked for but Warp cannot use CUDA (no NVIDIA driver found, libcuda.so, or "
            "a CPU-only warp-lang build); install the NVIDIA driver and a CUDA warp-lang, or use device='cpu'"
        )
    return wp.device_from_torch(device)


@contextlib.contextmanager
def warp_stream(device: torch.device) -> Iterator[object]:
    """Run Warp launches on torch's current stream so that no extra synchronisation is needed."""
    import warp as wp

    wdev = warp_device(device)
    if device.type != "cuda" or wdev.stream.cuda_stream == torch.cuda.current_stream(device).cuda_stream:
        yield wdev  # CPU, or already inside (a render enters once; its steps nest): nothing to switch
        return
    # switching streams records and waits on an event: a few driver calls, about 20 us per entry
    with wp.ScopedStream(wp.stream_from_torch(device)):
        yield wdev
