"""ogscene3d: incremental open-vocabulary 3D semantic mapping with semantic Gaussians and a 3D scene graph.

The top level re-exports the public API; subpackages hold the rest (``ogscene3d.datasets``,
``ogscene3d.segmentation``, ``ogscene3d.mapping``, ``ogscene3d.graph``, ``ogscene3d.eval``,
``ogscene3d.viewer``). Every name loads on first use (PEP 562), so ``import ogscene3d`` imports no torch,
warp or open3d until something needs them.
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

from ._lazy import lazy_exports
from ._source_tree import mount_source_folders

mount_source_folders(__name__, Path(__file__).resolve().parent)

__version__ = "0.1.0"

__getattr__, __dir__ = lazy_exports(
    globals(),
    {
        ".camera": ["Camera"],
        ".config": ["Config", "load_config"],
        ".datasets": ["make_synthetic_scene", "open_dataset"],
        ".eval": ["evaluate_run"],
        ".frame": ["Frame"],
        ".gaussians": ["GaussianMap"],
        ".graph": ["SceneGraph"],
        ".mapping": ["Mapper"],
        ".rendering": ["SemanticRender", "rasterization", "render_semantics", "rendering_contribution"],
        ".segmentation": ["Segmentation"],
        ".tracking": ["Tracker", "track", "track_sequence"],
    },
)

if TYPE_CHECKING:  # the same names, for type checkers and editors
    from .camera import Camera
    from .config import Config, load_config
    from .datasets import make_synthetic_scene, open_dataset
    from .eval import evaluate_run
    from .frame import Frame
    from .gaussians import GaussianMap
    from .graph import SceneGraph
    from .mapping import Mapper
    from .rendering import SemanticRender, rasterization, render_semantics, rendering_contribution
    from .segmentation import Segmentation
    from .tracking import Tracker, track, track_sequence

__all__ = [
    "Camera",
    "Config",
    "Frame",
    "GaussianMap",
    "Mapper",
    "SceneGraph",
    "Segmentation",
    "SemanticRender",
    "Tracker",
    "evaluate_run",
    "load_config",
    "make_synthetic_scene",
    "open_dataset",
    "rasterization",
    "render_semantics",
    "rendering_contribution",
    "track",
    "track_sequence",
    "__version__",
]
