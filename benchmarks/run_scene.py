r"""Whole run per scene: map each scene end to end and print one comparable row per scene.

Columns: frames, keyframes, Gaussians, per-module seconds (from the run's timings.json), mapping
seconds (process + finalize) and frames per second, peak host RSS and peak CUDA memory, and 3D
mIoU / F-mIoU / mAcc from ``ogscene3d.eval.evaluate_run`` when the scene has ground truth (synthetic
scenes always do; others need ``gt`` in a scenes file). No timed asserts anywhere: this only reports.

Each scene runs in a fresh process (spawn), so the peak RSS is that scene's own; before the measured
scene the process maps a 3-frame 48x36 synthetic scene so that Warp module loading and first-call
costs stay out of the per-module figures (``--no-warmup`` keeps them in).

    python benchmarks/run_scene.py synthetic:0 synthetic:1 --config configs/synthetic.yaml --device cpu
    python benchmarks/run_scene.py --scenes-file scenes.yaml --config configs/replica.yaml --device cuda
    python benchmarks/run_scene.py synthetic:0 --set synthetic.frames=20 --set synthetic.width=96 \
        --set synthetic.height=72 --json out.json
"""

from __future__ import annotations

import argparse
import json
import multiprocessing as mp
import sys
import tempfile
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _common import print_table, run_main  # noqa: E402

from ogscene3d.batch import (  # noqa: E402
    EvalOptions,
    SceneSpec,
    aggregate,
    json_safe,
    map_scene,
    parse_scene_entry,
    read_scenes_file,
)
from ogscene3d.device import resolve_device  # noqa: E402


def _measure(
    spec: SceneSpec,
    out: str,
    config: str | None,
    overrides: list[str],
    device: str | None,
    protocol: str,
    warmup: bool,
) -> dict:
    """Runs in the child process: optional warm-up, the measured run, then the evaluation."""
    from ogscene3d.batch import evaluate_scene
    from ogscene3d.eval import find_ground_truth

    if warmup:
        tiny = SceneSpec("_warmup", synthetic_seed=12345)
        with tempfile.TemporaryDirectory() as tmp:
            map_scene(
                tiny,
                tmp,
                config,
                [
                    *overrides,
                    "data.kind=auto",
                    "synthetic.frames=3",
                    "synthetic.width=48",
                    "synthetic.height=36",
                ],
                device,
            )
    rec = map_scene(spec, out, config, overrides, device)
    timings = json.loads((Path(rec["run_dir"]) / "timings.json").read_text())
    rec["module_seconds"] = timings["seconds"]
    gt = spec.gt or find_ground_truth(rec["run_dir"])
    if gt is not None:
        t0 = time.perf_counter()
        ev = evaluate_scene(
            rec["run_dir"], gt, EvalOptions(protocols=(protocol,), plots=False), rec["device"]
        )
        rec["semantic_3d"] = ev["semantic_3d"]
        rec["label_mapping"] = ev["label_mapping"]
        rec["eval_seconds"] = time.perf_counter() - t0
    return rec


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("scenes", nargs="*", help="dataset folders or synthetic:SEED")
    ap.add_argument("--scenes-file", type=Path, default=None, help="text/YAML scenes file (see run-batch)")
    ap.add_argument("--config", default=None, help="YAML config (e.g. configs/synthetic.yaml)")
    ap.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE")
    ap.add_argument("--device", default=None, help="cpu, cuda (default: config, else CUDA if present)")
    ap.add_argument("--out", default=None, help="where the runs go (default: a temporary folder)")
    ap.add_argument("--protocol", default="hovsg", choices=["hovsg", "conceptgraphs"])
    ap.add_argument("--no-warmup", action="store_true", help="keep first-call costs in the figures")
    ap.add_argument("--json", type=Path, default=None, help="also write the rows as JSON")
    args = ap.parse_args(argv)

    specs = read_scenes_file(args.scenes_file) if args.scenes_file else []
    here = Path.cwd()
    for i, s in enumerate(args.scenes):
        d = parse_scene_entry(s, here, f"argument {i + 1}")
        d.setdefault(
            "name",
            f"{len(specs)}_"
            + (f"synthetic_{d['synthetic_seed']}" if "synthetic_seed" in d else Path(d["data"]).name),
        )
        specs.append(SceneSpec(**d))
    if not specs:
        ap.error("give scenes as arguments or --scenes-file")
    if args.device is not None:
        resolve_device(args.device)  # no CUDA GPU: one line now, not one failure per scene
    tmp = None
    out = args.out
    if out is None:
        tmp = tempfile.TemporaryDirectory(prefix="ogscene3d_bench_")
        out = tmp.name

    records = []
    ctx = mp.get_context("spawn")
    for spec in specs:
        print(f"mapping {spec.name} ({spec.describe()}) ...", file=sys.stderr, flush=True)
        # one fresh process per scene: peak RSS is the scene's own, no state leaks between scenes
        with ProcessPoolExecutor(max_workers=1, mp_context=ctx) as ex:
            fut = ex.submit(
                _measure,
                spec,
                out,
                args.config,
                args.overrides,
                args.device,
                args.protocol,
                not args.no_warmup,
            )
            try:
                records.append(fut.result())
            except Exception as e:  # noqa: BLE001 - report the scene and go on with the others
                print(f"  {spec.name} failed: {type(e).__name__}: {e}", file=sys.stderr)
                records.append({"name": spec.name, "status": "failed", "error": f"{type(e).__name__}: {e}"})

    ok = [r for r in records if r.get("status") == "ok"]
    modules: dict[str, float] = {}
    for r in ok:
        for k, v in r["module_seconds"].items():
            modules[k] = modules.get(k, 0.0) + v
    mod_cols = sorted(modules, key=lambda k: -modules[k])
    rows = []
    for r in records:
        row = {"scene": r["name"], "status": r.get("status")}
        if r.get("status") == "ok":
            row.update(
                frames=r["frames"],
                kf=r["keyframes"],
                gaussians=r["gaussians"],
                **{f"{m} s": r["module_seconds"].get(m, 0.0) for m in mod_cols},
                **{"map s": r["map_seconds"], "fps": r["fps"], "RSS MiB": r["peak_rss_mb"]},
                **{"CUDA MiB": r["peak_cuda_mb"]},
            )
            sem = (r.get("semantic_3d") or {}).get(args.protocol)
            if sem:
                row.update({k: None if sem[m] is None else 100 * sem[m] for k, m in
                            (("mIoU", "miou"), ("F-mIoU", "fmiou"), ("mAcc", "macc"))})  # fmt: skip
        rows.append(row)
    cols = ["scene", "status", "frames", "kf", "gaussians", *(f"{m} s" for m in mod_cols)]
    cols += ["map s", "fps", "RSS MiB", "CUDA MiB", "mIoU", "F-mIoU", "mAcc"]
    if len(ok) > 1:
        keys = [c for c in cols[2:]]
        flat = [{"status": "ok", **{k: row.get(k) for k in keys}} for row in rows if row["status"] == "ok"]
        agg = aggregate(flat, keys)
        rows.append(
            {"scene": "mean", "status": f"{len(ok)}/{len(records)}", **{k: agg[k]["mean"] for k in keys}}
        )
        rows.append({"scene": "std", "status": "", **{k: agg[k]["std"] for k in keys}})
    dev = ok[0]["device"] if ok else args.device
    print(f"\nwhole run per scene on {dev} (warm-up {'off' if args.no_warmup else 'on'}); "
          f"module columns are seconds summed over the run (timings.json)")  # fmt: skip
    print_table(rows, cols)
    if ok and any(r.get("semantic_3d") for r in ok):
        first = next(r for r in ok if r.get("semantic_3d"))
        print(
            f"3D metrics in %: {first['semantic_3d'][args.protocol]['protocol']}; scene labels named by "
            f"{first['label_mapping']} mapping (overlap: majority overlap with GT instances, an oracle)"
        )
    for r in records:
        if r.get("status") != "ok":
            print(f"failed: {r['name']}: {r['error']}")
    if args.json:
        args.json.write_text(json.dumps(json_safe({"rows": rows, "runs": records}), indent=2) + "\n")
        print(f"wrote {args.json}")
    if tmp is not None:
        tmp.cleanup()
    return 0 if len(ok) == len(records) else 1


if __name__ == "__main__":
    run_main(main)
