"""Warp start-up on a machine without an NVIDIA driver: quiet, and a clear error when CUDA is asked for."""

from __future__ import annotations

import os
import subprocess
import sys

import pytest
import torch

from ogscene3d.device import NO_DRIVER_WARNING, _without_driver_warning, init_warp, warp_device
from ogscene3d.errors import ConfigError

no_driver = pytest.mark.skipif(init_warp().is_cuda_available(), reason="this machine has a CUDA driver")


@no_driver
def test_warp_starts_without_the_driver_warning():
    code = "from ogscene3d.device import init_warp; init_warp()"
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr
    assert NO_DRIVER_WARNING not in proc.stderr + proc.stdout


def test_other_native_stderr_output_is_passed_on(capfd):
    with _without_driver_warning():
        os.write(2, f"Warp CUDA warning: {NO_DRIVER_WARNING}. GPU execution unavailable.\n".encode())
        os.write(2, b"Warp CUDA error: something else\n")
    err = capfd.readouterr().err
    assert NO_DRIVER_WARNING not in err
    assert "Warp CUDA error: something else" in err


@no_driver
def test_asking_warp_for_cuda_without_a_driver_is_a_clear_error():
    with pytest.raises(ConfigError, match="NVIDIA driver"):
        warp_device(torch.device("cuda", 0))
