"""Registers, spills and occupancy of the blending kernels, from NVRTC's cubins: no GPU needed.

    python benchmarks/kernel_resources.py                 # sm_89 (RTX 4090) and sm_90 (H100)
    python benchmarks/kernel_resources.py --arch 90 --channels 3 --buffer-size 8

The blending kernels are latency-bound: how many 256-thread blocks an SM holds at once is set by their
register count, and a change that adds a few registers can cost more than it saves (the semantic vote at
103 registers, two blocks per SM, ran 25-28% slower on an H100 than at 76, three blocks). Spilled
registers go to local memory, counted in the cubin's stack frame (with any local arrays). Warp's wheel
ships NVRTC, so this runs anywhere.
"""

from __future__ import annotations

import argparse
import struct
import sys
import tempfile
from pathlib import Path

REGISTERS_PER_SM = 65536
REGISTER_GRANULE = 8  # registers are allocated per thread in multiples of 8 (per warp, of 256)
MAX_WARPS_PER_SM = {89: 48, 90: 64}
MAX_BLOCKS_PER_SM = {89: 24, 90: 32}

# .nv.info attributes (format EIFMT_SVAL: u16 size, then u32 symbol index, u32 value)
_EIFMT_NVAL, _EIFMT_BVAL, _EIFMT_HVAL, _EIFMT_SVAL = 1, 2, 3, 4
_ATTRIBUTES = {0x2F: "registers", 0x11: "frame_bytes"}


def _sections(data: bytes) -> list[tuple[str, int, int, int, int]]:
    """(name, type, offset, size, link) of each section of a 64-bit little-endian ELF."""
    if data[:4] != b"\x7fELF" or data[4] != 2 or data[5] != 1:
        raise ValueError("not a 64-bit little-endian ELF file")
    shoff = struct.unpack_from("<Q", data, 0x28)[0]
    entsize, count, names_index = struct.unpack_from("<HHH", data, 0x3A)
    raw = [struct.unpack_from("<IIQQQQIIQQ", data, shoff + i * entsize) for i in range(count)]
    names_offset = raw[names_index][4]

    def name(offset: int) -> str:
        start = names_offset + offset
        return data[start : data.index(b"\0", start)].decode()

    return [(name(s[0]), s[1], s[4], s[5], s[6]) for s in raw]


def cubin_resources(path: Path) -> dict[str, dict[str, int]]:
    """``{kernel symbol: {"registers": n, "frame_bytes": n}}`` from a cubin's .nv.info section."""
    data = Path(path).read_bytes()
    sections = _sections(data)
    symtab = next(s for s in sections if s[1] == 2)  # SHT_SYMTAB
    strtab_offset = sections[symtab[4]][2]
    symbols = []
    for i in range(symtab[3] // 24):
        (name_offset,) = struct.unpack_from("<I", data, symtab[2] + i * 24)
        start = strtab_offset + name_offset
        symbols.append(data[start : data.index(b"\0", start)].decode())
    out: dict[str, dict[str, int]] = {}
    for name, _, offset, size, _ in sections:
        if name != ".nv.info":
            continue
        pos, end = offset, offset + size
        while pos < end:
            fmt, attribute = data[pos], data[pos + 1]
            if fmt == _EIFMT_SVAL:
                (length,) = struct.unpack_from("<H", data, pos + 2)
                if attribute in _ATTRIBUTES and length == 8:
                    symbol, value = struct.unpack_from("<II", data, pos + 4)
                    out.setdefault(symbols[symbol], {})[_ATTRIBUTES[attribute]] = value
                pos += 4 + length
            elif fmt == _EIFMT_HVAL:
                pos += 4
            elif fmt == _EIFMT_BVAL:
                pos += 3
            elif fmt == _EIFMT_NVAL:
                pos += 2
            else:
                raise ValueError(f"{path}: unknown .nv.info format {fmt} at byte {pos}")
    return out


def blocks_per_sm(registers: int, block_dim: int, arch: int) -> int:
    """Blocks of ``block_dim`` threads an SM holds at once, by registers and by its warp/block limits."""
    per_thread = -(-max(registers, 1) // REGISTER_GRANULE) * REGISTER_GRANULE
    by_registers = REGISTERS_PER_SM // (per_thread * block_dim)
    by_warps = MAX_WARPS_PER_SM[arch] // (block_dim // 32)
    return min(by_registers, by_warps, MAX_BLOCKS_PER_SM[arch])


def blend_kernels(channels: list[int], buffer_size: int) -> list[tuple[str, object]]:
    """(label, Warp kernel) of the raster kernels for each channel count and the semantic kernels."""
    from ogscene3d.kernels.raster import raster_kernels
    from ogscene3d.kernels.semantic import semantic_kernel

    out = []
    for c in channels:
        fwd, bwd = raster_kernels(c)
        out += [(f"rasterize_forward ({c} ch)", fwd), (f"rasterize_backward ({c} ch)", bwd)]
    return out + [(f"semantic_render (buffer {buffer_size})", semantic_kernel(buffer_size))]


def kernel_resources(kernel, arch: int, workdir: Path) -> dict[str, int]:
    """Registers and stack frame of one Warp kernel compiled for ``arch`` (e.g. 90)."""
    import warp as wp

    out = workdir / f"{kernel.key}_sm{arch}"
    paths = wp.compile_aot_module(kernel.module, arch=arch, module_dir=str(out), use_ptx=False)
    for path in paths:
        if path.suffix == ".cubin":
            entry = [
                v
                for sym, v in cubin_resources(path).items()
                if sym.endswith("_cuda_kernel_forward") and "registers" in v
            ]
            if len(entry) == 1:
                return {"registers": entry[0]["registers"], "frame_bytes": entry[0].get("frame_bytes", 0)}
    raise RuntimeError(f"no cubin with one kernel entry for {kernel.key} (sm_{arch}) in {out}")


def main() -> None:
    # imported here: the tests load this module for its functions, without the benchmarks' torch helpers
    sys.path.insert(0, str(Path(__file__).resolve().parent))
    from _common import positive_int

    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--arch", type=int, action="append", choices=sorted(MAX_WARPS_PER_SM))
    ap.add_argument("--channels", default="1,3", help="colour channel counts of the raster kernels")
    ap.add_argument(
        "--buffer-size", type=positive_int, default=8, help="the semantic kernels' per-pixel buffer"
    )
    args = ap.parse_args()
    from ogscene3d.device import init_warp

    wp = init_warp()
    from ogscene3d.kernels.raster import BLEND_BLOCK_DIM

    archs = args.arch or sorted(MAX_WARPS_PER_SM)
    missing = [a for a in archs if a not in wp.get_cuda_supported_archs()]
    if missing:
        sys.exit(f"this Warp build cannot compile for sm_{missing[0]} (no NVRTC for it)")
    kernels = blend_kernels([int(c) for c in args.channels.split(",")], args.buffer_size)
    print(f"{'kernel':<34} {'arch':>5} {'regs':>5} {'stack_B':>8} {'blocks/SM':>10} {'occupancy':>10}")
    with tempfile.TemporaryDirectory() as tmp:
        for label, kernel in kernels:
            for arch in archs:
                r = kernel_resources(kernel, arch, Path(tmp))
                blocks = blocks_per_sm(r["registers"], BLEND_BLOCK_DIM, arch)
                occupancy = blocks * BLEND_BLOCK_DIM / 32 / MAX_WARPS_PER_SM[arch]
                print(
                    f"{label:<34} {'sm_' + str(arch):>5} {r['registers']:>5} {r['frame_bytes']:>8} "
                    f"{blocks:>10} {occupancy:>10.0%}"
                )


if __name__ == "__main__":
    sys.path.insert(0, str(Path(__file__).resolve().parent))
    from _common import run_main

    run_main(main)
