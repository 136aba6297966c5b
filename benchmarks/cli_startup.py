"""How fast the command line answers: wall time of ``ogscene3d --help``, ``python -c "import ogscene3d"``
and each subcommand's ``--help`` (fresh interpreters, median of --runs), and what ``import ogscene3d``
loads. Target (issue #28): ``ogscene3d --help`` under 1 s on a laptop, with neither torch, warp nor open3d
imported.

    python benchmarks/cli_startup.py [--runs 3]
"""

from __future__ import annotations

import argparse
import json
import statistics
import subprocess
import sys
import time

HEAVY = ("torch", "warp", "open3d", "viser", "cv2", "numpy")
SUBCOMMANDS = ["run", "eval", "live", "synth", "segment", "track", "graph", "run-batch", "eval-batch",
               "render-demo", "config"]  # fmt: skip


def _wall(argv: list[str], runs: int) -> list[float]:
    times = []
    for _ in range(runs):
        t0 = time.perf_counter()
        subprocess.run(argv, check=True, capture_output=True)
        times.append(time.perf_counter() - t0)
    return times


def _loaded() -> dict:
    probe = (
        "import sys, json, ogscene3d\n"
        f"print(json.dumps({{'ours': sorted(m for m in sys.modules if m.startswith('ogscene3d')), "
        f"'heavy': [m for m in {HEAVY!r} if m in sys.modules]}}))"
    )
    out = subprocess.run([sys.executable, "-c", probe], check=True, capture_output=True, text=True).stdout
    return json.loads(out)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=3, help="fresh interpreters per line (default 3)")
    ap.add_argument("--subcommands", action="store_true", help="also time every subcommand's --help")
    args = ap.parse_args()
    cli = [sys.executable, "-m", "ogscene3d.cli"]
    rows = [
        ("python -c pass (interpreter start)", _wall([sys.executable, "-c", "pass"], args.runs)),
        ("python -c 'import ogscene3d'", _wall([sys.executable, "-c", "import ogscene3d"], args.runs)),
        ("ogscene3d --help", _wall([*cli, "--help"], args.runs)),
    ]
    if args.subcommands:
        rows += [(f"ogscene3d {c} --help", _wall([*cli, c, "--help"], args.runs)) for c in SUBCOMMANDS]
    width = max(len(name) for name, _ in rows)
    print(f"{'command':<{width}}  median s  runs")
    for name, times in rows:
        print(f"{name:<{width}}  {statistics.median(times):8.3f}  {', '.join(f'{t:.2f}' for t in times)}")
    loaded = _loaded()
    heavy = ", ".join(loaded["heavy"]) or "none"
    print(f"import ogscene3d loads {len(loaded['ours'])} ogscene3d modules; heavy ones: {heavy}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
