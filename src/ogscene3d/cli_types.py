"""argparse types shared by the commands (and the benchmarks): the CLI names the option in its message,
where a value would otherwise fail deep inside (a zero grid, stride, size or iteration count)."""

from __future__ import annotations

import argparse
from collections.abc import Callable


def _convert(text: str, kind: Callable[[str], int | float], expected: str) -> int | float:
    """``kind(text)``, or an argparse error saying what was ``expected``."""
    try:
        return kind(text)
    except ValueError as e:
        raise argparse.ArgumentTypeError(f"expected {expected}, got {text!r}") from e


def positive_int(text: str) -> int:
    """An integer >= 1."""
    value = int(_convert(text, int, "an integer >= 1"))
    if value < 1:
        raise argparse.ArgumentTypeError(f"expected an integer >= 1, got {value}")
    return value


def positive_float(text: str) -> float:
    """A finite number > 0."""
    value = float(_convert(text, float, "a number"))
    if not value > 0 or value == float("inf"):
        raise argparse.ArgumentTypeError(f"expected a finite number > 0, got {text}")
    return value


def unit_interval(text: str) -> float:
    """A number in [0, 1]."""
    value = float(_convert(text, float, "a number in [0, 1]"))
    if not 0.0 <= value <= 1.0:
        raise argparse.ArgumentTypeError(f"expected a number in [0, 1], got {value}")
    return value


def port(text: str) -> int:
    """A TCP port, 0 for any free one."""
    value = int(_convert(text, int, "a port number"))
    if not 0 <= value <= 65535:
        raise argparse.ArgumentTypeError(f"port must be from 0 to 65535 (0: any free port), got {value}")
    return value


def image_size(minimum: int = 1, example: str = "160x120") -> Callable[[str], tuple[int, int]]:
    """A ``WxH`` type with both sides >= ``minimum`` -> (width, height)."""

    def parse(text: str) -> tuple[int, int]:
        try:
            w, h = (int(v) for v in text.lower().split("x"))
        except ValueError as e:
            raise argparse.ArgumentTypeError(f"expected WxH such as {example}, got {text!r}") from e
        if w < minimum or h < minimum:
            raise argparse.ArgumentTypeError(f"width and height must be >= {minimum}, got {text!r}")
        return w, h

    return parse


def add_size_argument(
    parser: argparse.ArgumentParser,
    flag: str,
    help: str,  # noqa: A002 - argparse's word
    minimum: int = 1,
    default: tuple[int, int] | None = None,
) -> None:
    """Add a ``WxH`` option: :func:`image_size` with both sides >= ``minimum``, its error's example the
    ``default`` (else 160x120).

    Args:
        parser: the command's parser.
        flag: the option, e.g. ``"--size"``.
        help: its help.
        minimum: the smallest width and height.
        default: (width, height) when the option is not given; None: not given.
    """
    example = f"{default[0]}x{default[1]}" if default else "160x120"
    parser.add_argument(flag, type=image_size(minimum, example), default=default, metavar="WxH", help=help)


def rerun_viewer(text: str) -> str:
    """``--rerun``'s value: a Rerun viewer's URL (``rerun+http://HOST:PORT/proxy``, ``rerun://...``), or
    ``spawn`` (what ``--rerun`` alone means: start a viewer here)."""
    if text != "spawn" and not text.startswith(("rerun://", "rerun+http://", "rerun+https://")):
        raise argparse.ArgumentTypeError(
            f"expected a Rerun viewer's URL such as rerun+http://127.0.0.1:9876/proxy, got {text!r}"
        )
    return text


def add_rerun_arguments(parser: argparse.ArgumentParser) -> None:
    """``--rerun [URL]`` and ``--rerun-save FILE.rrd`` (``run`` and ``live``; the ``rerun`` extra)."""
    parser.add_argument(
        "--rerun",
        nargs="?",
        const="spawn",
        default=None,
        type=rerun_viewer,
        metavar="URL",
        help="log the session to Rerun (per keyframe: camera pose and image, the map's points by label, the "
        "scene graph): start a Rerun viewer, or stream to the one at URL (rerun+http://HOST:9876/proxy); "
        'needs pip install "ogscene3d[rerun]"',
    )
    parser.add_argument(
        "--rerun-save",
        default=None,
        metavar="FILE.rrd",
        help="log the session to Rerun into this .rrd file (open it with `rerun FILE.rrd`)",
    )
