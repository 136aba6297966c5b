"""Wall time per keyframe of the mapper's semantic modules, this tree against a base revision, side by side.

    python benchmarks/semantic_ab.py prepare 23b0e14 .ab/base          # lay out the base revision's package
    python benchmarks/mapping_semantic_ab.py .ab/base SCENE --rounds 2 --device cpu [--set KEY=VALUE ...]

Maps the synthetic scene SCENE (``ogscene3d synth``) with the full system (``mapping.ablation: full``, the
scene graph off) in fresh processes, this tree and the base (``PYTHONPATH=DIR``) in turn for ``--rounds``
rounds, and compares the per-keyframe time of the semantic modules from each run's ``timings.json``: the local
association (with the duplicate merge), long-term, refinement and, where present, the evidence step
(``mapping/evidence.py``). Median over rounds; the ratio this / base is what issue 26 bounds (<= 1.5). The
times are ``timings.json``'s ``ms_per_keyframe``, wall-clock: run it alone on the machine. (The per-keyframe
CPU times that ``semantic_growth.py`` reads count every thread of the process, and read higher.)
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
sys.path.insert(0, str(HERE))
from _common import positive_int  # noqa: E402

SEMANTIC = ("local", "longterm", "refine", "evidence")

_MAP = """
import json, sys
from ogscene3d.config import load_config
from ogscene3d.mapping.ablation import map_sequence
from ogscene3d.datasets import open_dataset
cfg = load_config(sys.argv[1], ["mapping.ablation=full", "graph.enabled=false", *sys.argv[5:]])
m = map_sequence(cfg, open_dataset(sys.argv[2], config=cfg.data), sys.argv[3], sys.argv[4])
"""


def _run(
    tree: str, baseline: Path | None, scene: Path, device: str, config: Path, overrides: list[str]
) -> dict[str, float]:
    env = dict(os.environ)
    if baseline is not None:
        env["PYTHONPATH"] = os.pathsep.join(filter(None, [str(baseline.resolve()), env.get("PYTHONPATH")]))
    with tempfile.TemporaryDirectory() as tmp:
        cmd = [sys.executable, "-c", _MAP, str(config), str(scene), tmp, device, *overrides]
        proc = subprocess.run(cmd, env=env, cwd=ROOT, capture_output=True, text=True)
        if proc.returncode:
            raise SystemExit(f"mapping failed for {tree} (exit {proc.returncode}):\n{proc.stderr[-2000:]}")
        t = json.loads((Path(tmp) / "timings.json").read_text())
    ms = t["ms_per_keyframe"]
    row = {k: float(ms.get(k, 0.0)) for k in SEMANTIC}
    row["semantic"] = sum(row.values())
    print(f"--- {tree}: " + "  ".join(f"{k} {v:.1f}" for k, v in row.items()) + " ms/keyframe", flush=True)
    return row


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("base", type=Path, help="folder laid out by 'semantic_ab.py prepare REV DIR'")
    ap.add_argument("scene", type=Path, help="a synthetic scene folder")
    ap.add_argument("--rounds", type=positive_int, default=2)
    ap.add_argument("--device", default="cpu")
    ap.add_argument("--config", type=Path, default=ROOT / "configs" / "synthetic.yaml")
    ap.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE")
    args = ap.parse_args()
    if not (args.base / "ogscene3d").is_dir():
        raise SystemExit(
            f"{args.base} holds no ogscene3d package: run 'semantic_ab.py prepare REV {args.base}'"
        )
    rev = (
        (args.base / "REVISION").read_text().strip() if (args.base / "REVISION").exists() else str(args.base)
    )
    rows: dict[str, list[dict[str, float]]] = {"this tree": [], rev: []}
    for _ in range(args.rounds):
        here = _run("this tree", None, args.scene, args.device, args.config, args.overrides)
        rows["this tree"].append(here)
        rows[rev].append(_run(rev, args.base, args.scene, args.device, args.config, args.overrides))
    med = {
        t: {k: statistics.median(r[k] for r in rs) for k in (*SEMANTIC, "semantic")} for t, rs in rows.items()
    }
    print(f"median over {args.rounds} round(s), ms per keyframe")
    print(f"{'tree':>12}  " + "  ".join(f"{k:>9}" for k in (*SEMANTIC, "semantic")))
    for t, m in med.items():
        print(f"{t[:12]:>12}  " + "  ".join(f"{m[k]:>9.1f}" for k in (*SEMANTIC, "semantic")))
    base = med[rev]["semantic"]
    print(f"semantic wall time per keyframe, this / base: {med['this tree']['semantic'] / base:.3f}")


if __name__ == "__main__":
    main()
