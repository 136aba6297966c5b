"""ogscene3d: incremental open-vocabulary 3D semantic mapping with semantic Gaussians and a 3D scene graph."""

from .camera import Camera
from .config import Config, load_config
from .datasets import make_synthetic_scene, open_dataset
from .frame import Frame
from .render import rasterization
from .semantics import SemanticRender, render_semantics, rendering_contribution

__version__ = "0.1.0"

__all__ = [
    "Camera",
    "Config",
    "Frame",
    "load_config",
    "make_synthetic_scene",
    "open_dataset",
    "rasterization",
    "render_semantics",
    "rendering_contribution",
    "SemanticRender",
    "__version__",
]
