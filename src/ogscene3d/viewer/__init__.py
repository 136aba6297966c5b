"""ogscene3d.viewer: the live web viewer (viser) of the map and the scene graph (``ogscene3d-live``).

Producers build :class:`MapSnapshot` objects (``snapshot_from_mapper`` for a live Mapper, ``load_run``
for a saved run) and hand them to :meth:`LiveViewer.publish`; :class:`LiveSession` runs a mapper on a
background thread and does that between frames. viser is imported only when a viewer is created."""

from __future__ import annotations

from .._lazy import lazy_exports

__getattr__, __dir__ = lazy_exports(
    globals(),
    {
        ".app": ["LiveViewer", "MappingControl"],
        ".live": ["LiveSession"],
        ".runs": ["RunInfo", "load_run"],
        ".scene": ["ViewerSettings"],
        ".snapshot": ["MapSnapshot", "empty_snapshot", "snapshot_from_mapper"],
    },
)

__all__ = [
    "LiveSession",
    "LiveViewer",
    "MapSnapshot",
    "MappingControl",
    "RunInfo",
    "ViewerSettings",
    "empty_snapshot",
    "load_run",
    "snapshot_from_mapper",
]
