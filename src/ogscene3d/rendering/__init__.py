"""Rendering of semantic 3D Gaussians: the functional API over the Warp kernels of ``ogscene3d.kernels``.

- :func:`rasterization`: colour, depth or any number of channels alpha-blended per pixel, differentiable
  (gsplat's argument conventions);
- :func:`render_semantics`: confidence-weighted label voting (a :class:`SemanticRender`);
- :func:`rendering_contribution`: each Gaussian's rendering contribution and P_conf;
- :func:`render_demo`: a procedural scene rendered to an image (``ogscene3d render-demo``).

Behind this front, private modules: ``_projection`` (the EWA projection and tile binning both renderers
share, the Warp interop and the input checks), ``_rasterization``, ``_semantics`` and ``_demo``.
"""

from __future__ import annotations

from ._demo import render_demo
from ._rasterization import RENDER_MODES, rasterization
from ._semantics import SemanticRender, render_semantics, rendering_contribution

__all__ = [
    "RENDER_MODES",
    "SemanticRender",
    "rasterization",
    "render_demo",
    "render_semantics",
    "rendering_contribution",
]
