"""``ogscene3d models``: export SAM / MobileSAM / CLIP / YOLO-World checkpoints to the ONNX files the mapper
reads.

Model tools. `models export` loads a checkpoint you downloaded with its official package (pip install
'ogscene3d[export]' and the package named in the error) and writes ONNX files plus DIR/models.json; `ogscene3d
run --models DIR` then uses them. Several exports may share one DIR.

``ogscene3d models export KIND --checkpoint PATH --out DIR`` writes the ONNX exports of the official model
releases plus the manifest that ``ogscene3d run --models DIR`` reads (the logic: :mod:`ogscene3d.models`).
"""

from __future__ import annotations

import argparse

from ..models.export import KINDS, export_models
from .options import add_command, add_shared_arguments


def add_parser(subparsers) -> None:
    p = add_command(subparsers, __doc__, lambda args: (p.print_help(), 2)[1])
    sub = p.add_subparsers(dest="models_command", metavar="ACTION")
    e = sub.add_parser("export", help="export one model kind into DIR")
    e.add_argument("kind", choices=list(KINDS), help="what the checkpoint is")
    e.add_argument(
        "--checkpoint",
        required=True,
        help="the official checkpoint: SAM/MobileSAM .pth, open_clip weights file, Hugging Face CLIP folder, "
        "YOLO-World .pt",
    )
    add_shared_arguments(e, "--out", out="models folder to write (models.json is updated)")
    e.add_argument("--arch", default=None, help="open-clip: the model name, e.g. ViT-B-32")
    e.add_argument(
        "--classes", default=None, help="yolo-world: the vocabulary, comma-separated (chair,table,lamp)"
    )
    e.add_argument("--image-size", type=int, default=None, help="yolo-world: input size (default 640)")
    e.add_argument(
        "--text-embeddings",
        default=None,
        help="yolo-world: .npy [K, 512] of the classes' CLIP text embeddings, instead of set_classes (which "
        "downloads CLIP)",
    )
    e.add_argument("--opset", type=int, default=17, help="ONNX opset (default 17)")
    e.set_defaults(func=run_export)


def run_export(args: argparse.Namespace) -> int:
    classes = [c.strip() for c in args.classes.split(",") if c.strip()] if args.classes else None
    path = export_models(
        args.kind,
        args.checkpoint,
        args.out,
        arch=args.arch,
        classes=classes,
        image_size=args.image_size,
        opset=args.opset,
        text_embeddings=args.text_embeddings,
    )
    print(f"{args.kind} exported; manifest {path} (use it with: ogscene3d run --models {args.out})")
    return 0
