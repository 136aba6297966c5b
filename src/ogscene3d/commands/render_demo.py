"""``ogscene3d render-demo``: render a procedural Gaussian scene to a PNG (rasterizer smoke test)."""

from __future__ import annotations

import argparse
from pathlib import Path

from ..cli_types import add_size_argument, positive_int
from .options import add_command, add_shared_arguments

# argparse types: the CLI names the option in its message (the library checks again, naming the argument)


def _image_path(text: str) -> Path:
    import cv2

    if not cv2.haveImageWriter(text):
        raise argparse.ArgumentTypeError(
            f"{text!r} is not an image file name OpenCV can write; end it in .png (or .jpg)"
        )
    return Path(text)


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = add_command(sub, __doc__, _run)
    add_shared_arguments(
        p,
        "--out",
        out={
            "required": False,
            "type": _image_path,
            "default": Path("outputs/render_demo.png"),
            "help": "image file to write, e.g. render.png (default outputs/render_demo.png)",
        },
    )
    p.add_argument("--gaussians", type=positive_int, default=20000, help="Gaussians (default 20000)")
    add_size_argument(p, "--size", "each view's size (320x240)", default=(320, 240))
    p.add_argument("--views", type=positive_int, default=4, help="orbit views side by side (default 4)")
    add_shared_arguments(p, "--device", device="cpu, cuda or cuda:N (default: cuda when available)")


def _run(args: argparse.Namespace) -> int:
    from ..rendering import render_demo

    w, h = args.size
    path = render_demo(args.out, args.gaussians, w, h, args.views, args.device)
    print(f"wrote {path}")
    return 0
