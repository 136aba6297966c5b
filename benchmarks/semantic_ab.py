"""The semantic call of this tree against an earlier revision's, on the same machine in one session.

    python benchmarks/semantic_ab.py prepare f5c2db7 .ab/base       # where git is: lay out that revision
    python benchmarks/semantic_ab.py run .ab/base --device cuda      # on the GPU: alternate the two trees

``prepare`` writes the package ``ogscene3d`` (with its kernels) of a git revision under DIR (``.ab/`` is
git-ignored: name it in the device tool's carry to take it to a borrowed GPU machine). ``run`` times
``semantic.py`` in fresh processes, this tree and the baseline (``PYTHONPATH=DIR``) in turn for
``--rounds`` rounds, and prints per scene the device-kernel and wall times of both, their ratio, and each
one's ratio to a colour forward of the same scene. f5c2db7 is the last revision with two semantic kernels
(a vote and a contribution pass), the one timed on an H100 in docs/results.md.
"""

from __future__ import annotations

import argparse
import io
import json
import os
import statistics
import subprocess
import sys
import tarfile
import tempfile
from pathlib import Path

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
sys.path.insert(0, str(HERE))
from _common import positive_int  # noqa: E402


def prepare(rev: str, dest: Path) -> None:
    archive = subprocess.run(
        ["git", "archive", "--format=tar", rev, "src/ogscene3d", "kernels"],
        cwd=ROOT,
        check=True,
        capture_output=True,
    ).stdout
    package = dest / "ogscene3d"
    if package.exists():
        raise SystemExit(f"{package} exists: remove it or pick another folder")
    with tempfile.TemporaryDirectory() as tmp, tarfile.open(fileobj=io.BytesIO(archive)) as tar:
        # a trusted archive of our own history; the filter keyword exists from Python 3.12 (and 3.11.4)
        tar.extractall(tmp, **({"filter": "data"} if hasattr(tarfile, "data_filter") else {}))
        dest.mkdir(parents=True, exist_ok=True)
        os.replace(Path(tmp) / "src" / "ogscene3d", package)
        os.replace(Path(tmp) / "kernels", package / "kernels")  # the package-dir mapping of pyproject.toml
    (dest / "REVISION").write_text(rev + "\n")
    print(f"{rev} laid out in {package}")


def _bench(tree: str, baseline: Path | None, passthrough: list[str]) -> list[dict]:
    env = dict(os.environ)
    if baseline is not None:
        env["PYTHONPATH"] = os.pathsep.join(filter(None, [str(baseline.resolve()), env.get("PYTHONPATH")]))
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "rows.json"
        cmd = [sys.executable, str(HERE / "semantic.py"), "--json", str(out), *passthrough]
        proc = subprocess.run(cmd, env=env, cwd=ROOT, capture_output=True, text=True)
        print(f"--- {tree}\n{proc.stdout}{proc.stderr[-2000:] if proc.returncode else ''}", flush=True)
        if proc.returncode:
            raise SystemExit(f"semantic.py failed for {tree} (exit {proc.returncode})")
        rows = json.loads(out.read_text())
    # semantic.py writes figures it did not measure (kernel times on the CPU) as null: back to NaN here
    return [{k: float("nan") if v is None else v for k, v in row.items()} for row in rows]


def run(baseline: Path, rounds: int, passthrough: list[str]) -> None:
    if not (baseline / "ogscene3d" / "kernels").is_dir():
        raise SystemExit(
            f"{baseline} holds no ogscene3d package: run 'semantic_ab.py prepare REV {baseline}'"
        )
    rev = (baseline / "REVISION").read_text().strip() if (baseline / "REVISION").exists() else str(baseline)
    results: dict[str, list[list[dict]]] = {"this tree": [], rev: []}
    for _ in range(rounds):
        results["this tree"].append(_bench("this tree", None, passthrough))
        results[rev].append(_bench(rev, baseline, passthrough))
    keys = ("1call_kernel_ms", "1call/color_kernels", "sem+contrib_1call_ms", "1call/color")
    print(f"median over {rounds} round(s); kernel = device-kernel time per call, wall = median wall time")
    print(f"{'scene':>9} {'N':>8}  {'tree':>12}  " + "  ".join(f"{k:>20}" for k in keys))
    for i, row in enumerate(results["this tree"][0]):
        medians = {}
        for tree, runs in results.items():
            medians[tree] = {k: statistics.median(r[i][k] for r in runs) for k in keys}
            values = "  ".join(f"{medians[tree][k]:>20.3f}" for k in keys)
            print(f"{row['scene']:>9} {row['N']:>8}  {tree[:12]:>12}  {values}")
        ratios = "  ".join(
            f"{medians['this tree'][k] / medians[rev][k] if medians[rev][k] else float('nan'):>20.3f}"
            for k in keys
        )
        print(f"{'':>9} {'':>8}  {'this / base':>12}  {ratios}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = ap.add_subparsers(dest="cmd", required=True)
    p = sub.add_parser("prepare", help="lay out a git revision's package under DIR")
    p.add_argument("rev")
    p.add_argument("dir", type=Path)
    r = sub.add_parser("run", help="time this tree and the baseline in turn (other args go to semantic.py)")
    r.add_argument("dir", type=Path)
    r.add_argument("--rounds", type=positive_int, default=2, help="rounds of both trees (default 2)")
    args, rest = ap.parse_known_args()
    if args.cmd == "prepare":
        if rest:
            ap.error(f"unknown arguments {rest}")
        prepare(args.rev, args.dir)
    else:
        run(args.dir, args.rounds, rest)


if __name__ == "__main__":
    main()
