"""Every Warp kernel compiles for the GPUs we target, on machines without one.

Warp's wheel ships NVRTC, so CUDA code generation and compilation run without a driver or a GPU.
The CPU tests execute the same kernel bodies, but Warp emits separate CUDA source for them; a
construct that only the CUDA backend rejects would otherwise surface on a user's GPU first.
sm_89 is the RTX 4090 class card of our users, sm_90 the H100 the benchmarks run on.
"""

from __future__ import annotations

import importlib
import pkgutil

import pytest
from ogscene3d.kernels.raster import raster_kernels
from ogscene3d.kernels.semantic import semantic_kernel

from ogscene3d import kernels
from ogscene3d.device import init_warp
from ogscene3d.rendering._rasterization import MAX_CHANNELS_PER_PASS
from ogscene3d.rendering._semantics import DEFAULT_BUFFER_SIZE

wp = init_warp()
TARGET_ARCHS = (89, 90)
FACTORY_FILES = ("raster", "semantic")  # kernels built per channel count / buffer size, compiled below
FUNCTION_FILES = ("lanes",)  # device functions only, compiled inside the kernels that call them
NOT_MODULE_KERNELS = FACTORY_FILES + FUNCTION_FILES


def _archs() -> list[int]:
    supported = set(wp.get_cuda_supported_archs())
    return [a for a in TARGET_ARCHS if a in supported]


ARCHS = _archs()
needs_nvrtc = pytest.mark.skipif(not ARCHS, reason="this Warp build cannot compile CUDA (no NVRTC)")


def _module_kernel_files() -> list[str]:
    return sorted(m.name for m in pkgutil.iter_modules(kernels.__path__))


def _compile(module, arch: int, tmp_path) -> None:
    paths = wp.compile_aot_module(module, arch=arch, module_dir=str(tmp_path), use_ptx=True)
    assert paths and all(p.exists() and p.stat().st_size > 0 for p in paths)


@needs_nvrtc
@pytest.mark.parametrize("arch", ARCHS)
@pytest.mark.parametrize("name", [n for n in _module_kernel_files() if n not in NOT_MODULE_KERNELS])
def test_module_kernels_compile_for_cuda(name: str, arch: int, tmp_path) -> None:
    module = importlib.import_module(f"ogscene3d.kernels.{name}")
    _compile(module, arch, tmp_path)


@needs_nvrtc
@pytest.mark.parametrize("arch", ARCHS)
@pytest.mark.parametrize("channels", [1, 3, MAX_CHANNELS_PER_PASS])  # depth, RGB, a full blending chunk
def test_raster_kernels_compile_for_cuda(channels: int, arch: int, tmp_path) -> None:
    for kernel in raster_kernels(channels):
        _compile(kernel.module, arch, tmp_path)


@needs_nvrtc
@pytest.mark.parametrize("arch", ARCHS)
@pytest.mark.parametrize("buffer_size", [1, DEFAULT_BUFFER_SIZE, 64])  # bounds and default
def test_semantic_kernel_compiles_for_cuda(buffer_size: int, arch: int, tmp_path) -> None:
    _compile(semantic_kernel(buffer_size).module, arch, tmp_path)


def test_every_kernel_file_is_covered() -> None:
    # a new kernels/ file is compiled by the first test automatically; factories need listing above
    for name in _module_kernel_files():
        module = importlib.import_module(f"ogscene3d.kernels.{name}")
        has_module_kernels = any(isinstance(v, wp.Kernel) for v in vars(module).values())
        assert has_module_kernels or name in NOT_MODULE_KERNELS, f"kernels/{name}.py: nothing to compile"


def _kernel_resources_module():
    import importlib.util
    from pathlib import Path

    path = Path(__file__).resolve().parents[2] / "benchmarks" / "kernel_resources.py"
    spec = importlib.util.spec_from_file_location("kernel_resources", path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


@pytest.mark.skipif(90 not in ARCHS, reason="this Warp build cannot compile for sm_90")
def test_blend_kernels_keep_their_registers_on_the_h100(tmp_path) -> None:
    """The blending kernels are latency-bound: on the H100 the semantic vote at two blocks per SM ran 28%
    slower than at three, and spilling versions of it 20-90% slower. Both are visible in the cubin, so
    check them here, without a GPU."""
    from ogscene3d.kernels.raster import BLEND_BLOCK_DIM
    from ogscene3d.kernels.semantic import VOTE_BLOCKS_PER_SM

    res = _kernel_resources_module()
    for label, kernel in res.blend_kernels([1, 3], DEFAULT_BUFFER_SIZE):
        r = res.kernel_resources(kernel, 90, tmp_path)
        assert 0 < r["registers"] <= 255, label
        assert r["frame_bytes"] == 0, f"{label} spills {r['frame_bytes']} bytes on sm_90"
        if label.startswith("semantic_render"):
            assert res.blocks_per_sm(r["registers"], BLEND_BLOCK_DIM, 90) >= VOTE_BLOCKS_PER_SM


def test_blocks_per_sm_follows_register_allocation() -> None:
    res = _kernel_resources_module()
    assert res.blocks_per_sm(64, 256, 90) == 4
    assert res.blocks_per_sm(65, 256, 90) == 3  # 65 rounds up to 72 registers a thread
    assert res.blocks_per_sm(80, 256, 90) == 3
    assert res.blocks_per_sm(103, 256, 90) == 2
    assert res.blocks_per_sm(32, 256, 90) == 8
    assert res.blocks_per_sm(32, 256, 89) == 6  # Ada holds 48 warps an SM
