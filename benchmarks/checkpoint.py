"""What a mapping checkpoint costs once the long-term memory is full, and what a resume from it costs.

    python benchmarks/checkpoint.py [--size 1200x680] [--views 64] [--checkpoints 4] [--gaussians 200k]
                                    [--out DIR] [--json]

A mapper is given ``--gaussians`` Gaussians and a full memory of ``--views`` views (random RGB, depth and
segment ids at ``--size``), then writes ``--checkpoints`` checkpoints to ``OUT/map.npz``; between two
checkpoints one new view joins the memory and evicts the oldest, as in a long run (``checkpoint_every``).
Per checkpoint it reports the seconds ``Mapper.save_checkpoint`` took, the bytes the process wrote
(``wchar`` of /proc/self/io, where there is one) and the run directory's size. Then a fresh process
resumes from the last checkpoint (``Mapper.load_checkpoint``): its seconds, and its peak RSS over its
baseline after the imports. Nothing is asserted: this script only reports.
"""

from __future__ import annotations

import argparse
import json
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _common import parse_count, positive_int, run_main, synthetic_gaussians  # noqa: E402

from ogscene3d.cli_types import image_size  # noqa: E402
from ogscene3d.config import load_config  # noqa: E402
from ogscene3d.mapping.longterm import MemoryEntry  # noqa: E402
from ogscene3d.mapping.mapper import Mapper  # noqa: E402


def _written_bytes() -> int | None:
    """Bytes this process has passed to write() so far (Linux); None elsewhere."""
    try:
        for line in Path("/proc/self/io").read_text().splitlines():
            if line.startswith("wchar:"):
                return int(line.split()[1])
    except OSError:
        return None
    return None


def _peak_rss_mb() -> float:
    """This process's peak RSS. Linux's VmHWM starts anew at exec; ru_maxrss would keep the peak of the
    parent that spawned it (hundreds of MB of memory views)."""
    try:
        for line in Path("/proc/self/status").read_text().splitlines():
            if line.startswith("VmHWM:"):
                return int(line.split()[1]) / 1024
    except OSError:
        pass
    kb = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    return kb / 1024 if sys.platform != "darwin" else kb / 2**20


def _dir_bytes(path: Path) -> int:
    return sum(p.stat().st_size for p in path.rglob("*") if p.is_file())


def _config(views: int):
    return load_config(None, ["graph.enabled=false", f"mapping.longterm.memory_max={views}"])


def _view(keyframe: int, width: int, height: int, rng: np.random.Generator) -> MemoryEntry:
    K = np.array([[600.0, 0, width / 2], [0, 600.0, height / 2], [0, 0, 1]], dtype=np.float32)
    pose = np.eye(4)
    pose[:3, 3] = rng.normal(size=3)
    return MemoryEntry(
        keyframe,
        rng.integers(0, 256, (height, width, 3), dtype=np.uint8),
        rng.uniform(0.5, 4.0, (height, width)).astype(np.float32),
        K,
        pose,
        rng.integers(0, 200, (height, width), dtype=np.int32),
        {i: 0.9 for i in range(1, 200)},
    )


def save_run(args: argparse.Namespace) -> list[dict]:
    """Build the mapper and write the checkpoints; one record per checkpoint."""
    width, height = args.size
    device = torch.device("cpu")
    mapper = Mapper(_config(args.views), device)
    means, quats, scales, opac, colors, labels, conf = synthetic_gaussians(args.gaussians, device)
    mapper.map.append(means, colors, torch.log(scales), labels, conf, quats)
    rng = np.random.default_rng(0)
    for kf in range(args.views):
        mapper.memory.restore(_view(kf, width, height, rng), device)
    mapper.keyframe_count = mapper.frames_seen = mapper.next_index = args.views
    ckpt = args.out / "map.npz"
    rows = []
    for i in range(args.checkpoints):
        if i:  # a new view evicts the oldest, as a full memory does in a long run
            mapper.memory.restore(_view(args.views + i - 1, width, height, rng), device)
            mapper.keyframe_count += 1
        before = _written_bytes()
        t0 = time.perf_counter()
        mapper.save_checkpoint(ckpt)
        seconds = time.perf_counter() - t0
        after = _written_bytes()
        rows.append(
            {
                "checkpoint": i + 1,
                "seconds": seconds,
                "written_mb": (after - before) / 2**20 if before is not None and after is not None else None,
                "map_npz_mb": ckpt.stat().st_size / 2**20,
                "run_dir_mb": _dir_bytes(args.out) / 2**20,
            }
        )
    return rows


def resume(path: Path, views: int) -> dict:
    """Load the checkpoint ``path`` in this process: seconds and peak RSS (MB) before / after."""
    mapper = Mapper(_config(views), "cpu")
    base = _peak_rss_mb()
    t0 = time.perf_counter()
    mapper.load_checkpoint(path)
    seconds = time.perf_counter() - t0
    return {
        "seconds": seconds,
        "views": len(mapper.memory),
        "rss_before_mb": base,
        "peak_rss_mb": _peak_rss_mb(),
    }


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--size", type=image_size(1), default=(1200, 680), help="WxH of the memory views")
    p.add_argument("--views", type=positive_int, default=64, help="memory views (longterm.memory_max)")
    p.add_argument("--checkpoints", type=positive_int, default=4, help="checkpoints to write")
    p.add_argument("--gaussians", type=parse_count, default=200_000, help="Gaussians in the map (200k)")
    p.add_argument("--out", type=Path, default=None, help="run directory (default: a temporary one)")
    p.add_argument("--json", action="store_true", help="print one JSON object instead of a table")
    p.add_argument("--resume-only", type=Path, default=None, help=argparse.SUPPRESS)  # the child process
    args = p.parse_args()
    if args.resume_only is not None:
        print(json.dumps(resume(args.resume_only, args.views)))
        return 0
    with tempfile.TemporaryDirectory(prefix="ogscene3d-ckpt-") as tmp:
        if args.out is None:
            args.out = Path(tmp)
        args.out.mkdir(parents=True, exist_ok=True)
        rows = save_run(args)
        # a fresh process, so that the peak RSS is the resume's alone
        ckpt = str(args.out / "map.npz")
        cmd = [sys.executable, __file__, "--resume-only", ckpt, "--views", str(args.views)]
        child = subprocess.run(cmd, check=True, capture_output=True, text=True)
        loaded = json.loads(child.stdout.strip().splitlines()[-1])
    if args.json:
        report = {"size": list(args.size), "views": args.views, "checkpoints": rows, "resume": loaded}
        print(json.dumps(report))
        return 0
    w, h = args.size
    print(f"{args.views} memory views at {w}x{h}, {args.gaussians} Gaussians")
    print(f"{'checkpoint':>10}{'seconds':>10}{'written MB':>12}{'map.npz MB':>12}{'run dir MB':>12}")
    for r in rows:
        written = f"{r['written_mb']:.1f}" if r["written_mb"] is not None else "n/a"
        print(
            f"{r['checkpoint']:>10}{r['seconds']:>10.3f}{written:>12}{r['map_npz_mb']:>12.1f}"
            f"{r['run_dir_mb']:>12.1f}"
        )
    print(
        f"resume: {loaded['seconds']:.3f} s, {loaded['views']} views, peak RSS "
        f"{loaded['peak_rss_mb']:.0f} MB ({loaded['rss_before_mb']:.0f} MB before loading)"
    )
    return 0


if __name__ == "__main__":
    run_main(main)
