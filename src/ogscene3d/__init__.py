"""ogscene3d: incremental open-vocabulary 3D semantic mapping with semantic Gaussians and a 3D scene graph.

The top level re-exports the public API; subpackages hold the rest (``ogscene3d.datasets``,
``ogscene3d.segmentation``, ``ogscene3d.mapping``, ``ogscene3d.graph``, ``ogscene3d.eval``,
``ogscene3d.viewer``). Heavy optional dependencies (open3d, onnxruntime, viser, ray) load on first use.
"""

from .camera import Camera
from .config import Config, load_config
from .datasets import make_synthetic_scene, open_dataset
from .eval import evaluate_run
from .frame import Frame
from .gaussians import GaussianMap
from .graph import SceneGraph
from .mapping import Mapper
from .render import rasterization
from .semantics import SemanticRender, render_semantics, rendering_contribution
from .tracking import Tracker, track, track_sequence

__version__ = "0.1.0"

__all__ = [
    "Camera",
    "Config",
    "Frame",
    "GaussianMap",
    "Mapper",
    "SceneGraph",
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
