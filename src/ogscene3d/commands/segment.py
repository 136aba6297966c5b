"""``ogscene3d segment``: compute open-set 2D segments (SAM / SAM+detector / classical) for a dataset.

Run the 2D front-end of paper Sec. III-B.1 over every frame of --data and write the precomputed segments
format to --out (resumable: frames whose PNG exists are skipped). Backends: sam (SAM grid masks, M_s),
sam+detector (fused M_f of M_s and detector-prompted SAM masks), classical (weight-free graph segmentation,
lower quality), simulated (synthetic scenes with ground truth only).

Output (README "File formats"): ``OUT/<rgb stem>.png`` uint16 ids and ``OUT/<rgb stem>.json`` with
``{"scores": {"<id>": predicted IoU}, "names": {"<id>": detector class}}`` (``names`` only for
segments that came with a detector label). The JSON is written first and the PNG last, both
atomically, so a frame counts as done exactly when its PNG exists: an interrupted run resumes by
skipping those frames (``--overwrite`` redoes them).
"""

from __future__ import annotations

import argparse
import logging
import time
from pathlib import Path
from typing import TYPE_CHECKING

from ..cli_types import positive_int
from ..config import load_config
from ..errors import ConfigError, DataError
from ..progress import progress
from .options import add_command, add_override_argument, add_shared_arguments

if TYPE_CHECKING:
    from ..config import SegmentationConfig
    from ..segmentation.base import Segmentation

log = logging.getLogger(__name__)


def add_parser(subparsers) -> None:
    p = add_command(subparsers, __doc__, run)
    add_shared_arguments(
        p, "--data", "--out", data={"required": True}, out="folder to write <rgb stem>.png / .json into"
    )
    p.add_argument(
        "--backend",
        default=None,
        choices=["sam", "sam+detector", "classical", "simulated"],
        help="front-end (default: the config's segmentation.backend)",
    )
    p.add_argument("--sam-encoder", default=None, help="SAM image encoder ONNX file")
    p.add_argument("--sam-decoder", default=None, help="SAM prompt decoder ONNX file")
    p.add_argument("--detector", default=None, help="open-vocabulary detector ONNX file (YOLO-World style)")
    p.add_argument(
        "--classes",
        default=None,
        help="the detector's class names in export order: comma-separated, or a text file with one per line",
    )
    p.add_argument(
        "--points-per-side", type=positive_int, default=None, help="SAM grid prompts per side (default 32)"
    )
    p.add_argument("--provider", default=None, choices=["auto", "cpu", "cuda"], help="onnxruntime provider")
    add_shared_arguments(p, "--config", config="YAML config; its `segmentation` and `data` sections apply")
    add_override_argument(p, "segmentation.pred_iou_thresh=0.9")
    p.add_argument("--kind", default="auto", help="dataset layout (default: detected)")
    p.add_argument("--stride", type=int, default=None, help="use every N-th frame")
    add_shared_arguments(p, "--max-frames", max_frames="segment at most this many frames")
    p.add_argument("--overwrite", action="store_true", help="recompute frames that already have segments")
    add_shared_arguments(p, "--no-progress")


def parse_classes(text: str) -> list[str]:
    """Class names from ``a,b,c`` or from a text file with one name per line (blank lines ignored)."""
    path = Path(text)
    if path.is_file():
        names = [line.strip() for line in path.read_text().splitlines()]
    else:
        names = [c.strip() for c in text.split(",")]
    names = [n for n in names if n]
    if not names:
        raise ConfigError(f"--classes {text!r} lists no class names")
    return names


def write_frame_segments(out: Path, stem: str, seg: Segmentation) -> Path:
    """Write one frame's segments: the JSON (scores, names) first, the PNG (the 'done' marker) last."""
    from ..segmentation.precomputed import write_segments

    return write_segments(out, stem, seg.ids, seg.scores, seg.names)


def run(args: argparse.Namespace) -> int:
    from ..datasets import open_dataset
    from ..segmentation.factory import make_segmenter

    cfg = load_config(args.config, list(args.overrides))
    sc = _segmentation_settings(args, cfg.segmentation)
    ds = open_dataset(
        args.data, kind=args.kind, stride=args.stride, max_frames=args.max_frames, config=cfg.data
    )
    segmenter = make_segmenter(sc, getattr(ds, "K", None))
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    stems, todo = _frames_to_do(ds, out, args.overwrite)
    t0 = time.perf_counter()
    done, bad, n_segments = _segment_frames(args, cfg, ds, segmenter, out, stems, todo)
    dt = time.perf_counter() - t0
    if done:
        log.info(
            "segmented %d frames into %s (%.1f segments per frame, %.2f s per frame)",
            done,
            out,
            n_segments / done,
            dt / done,
        )
    elif bad:
        log.warning("no frame segmented: the %d left to do were bad and skipped", bad)
    else:
        log.info("nothing to do: all %d frames already have segments in %s", len(stems), out)
    return 0


def _segmentation_settings(args: argparse.Namespace, sc: SegmentationConfig) -> SegmentationConfig:
    """The config's ``segmentation`` section with this command's options applied."""
    if args.backend:
        sc.backend = args.backend
    if args.sam_encoder:
        sc.sam_encoder = args.sam_encoder
    if args.sam_decoder:
        sc.sam_decoder = args.sam_decoder
    if args.detector:
        sc.detector = args.detector
    if args.classes:
        sc.detector_classes = parse_classes(args.classes)
    if args.points_per_side is not None:
        sc.points_per_side = args.points_per_side
    if args.provider:
        sc.execution_provider = args.provider
    if sc.backend == "precomputed":
        raise ConfigError(
            "choose a segmentation backend with --backend (sam, sam+detector, classical, simulated)"
        )
    return sc


def _frames_to_do(ds, out: Path, overwrite: bool) -> tuple[list[str | None], list[int]]:
    """(each frame's file stem, None where the dataset has no file names; the frames to segment): frames
    whose PNG exists are done, decided from the file names alone, without reading images."""
    records = getattr(ds, "records", None)
    stems = [r.rgb_path.stem for r in records] if records is not None else [None] * len(ds)
    todo = [i for i, s in enumerate(stems) if overwrite or s is None or not _segmented(out, s)]
    skipped = len(stems) - len(todo)
    if skipped:
        log.info("%d of %d frames already segmented in %s: skipping them", skipped, len(stems), out)
    return stems, todo


def _segmented(out: Path, stem: str) -> bool:
    """Whether the frame ``stem`` is done: its PNG, written last, is in ``out``."""
    from ..segmentation.precomputed import segments_paths

    return segments_paths(out, stem)[0].exists()


def _segment_frames(
    args: argparse.Namespace, cfg, ds, segmenter, out: Path, stems: list[str | None], todo: list[int]
) -> tuple[int, int, int]:
    """Segment and write the ``todo`` frames. -> (frames done, bad frames, segments written)."""
    backend = cfg.segmentation.backend
    # frames the dataset left out as it opened (a broken file, under data.on_bad_frame: skip) are bad ones too
    done, bad, n_segments = 0, int(getattr(ds, "frames_left_out", 0) or 0), 0
    with progress(todo, desc=f"segment ({backend})", disable=args.no_progress) as bar:
        for i in bar:
            try:
                frame = ds[i]
            except DataError as e:
                if cfg.data.on_bad_frame == "skip":
                    log.warning("skipping frame %d: %s", i, e)
                    bad += 1
                    continue
                raise
            stem = stems[i] or frame.name or f"{frame.index:06d}"
            if stems[i] is None and not args.overwrite and _segmented(out, stem):
                continue
            if backend == "simulated":
                if frame.gt_instances is None:
                    raise DataError(
                        f"{args.data}: backend 'simulated' needs ground-truth instance maps, which only "
                        "synthetic scenes have; use sam, sam+detector or classical"
                    )
                seg = segmenter.segment_frame(frame)
            else:
                seg = segmenter(frame.rgb, frame.depth)
            write_frame_segments(out, stem, seg)
            done += 1
            n_segments += len(seg.scores)
            bar.set_postfix(segments=len(seg.scores))
    return done, bad, n_segments
