"""The mapper's files: its checkpoint (``map.npz``, written and restored by ``checkpoint.py``) and the run
folder it saves (``ogscene3d.runs.save_run``), as methods of :class:`~ogscene3d.mapping.mapper.Mapper`."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..gaussians import GaussianMap
from ..runs import save_run
from ..tracking import hold_last_good, trajectory_text
from .checkpoint import mapper_state, read_checkpoint, restore_mapper, write_checkpoint


class MapperFiles:
    """What :class:`~ogscene3d.mapping.mapper.Mapper` reads and writes (its base class: the methods use the
    mapper's map, timings, graph feed and counters)."""

    def state(self) -> dict[str, np.ndarray]:
        """The mapper's state besides the Gaussians, as the arrays of a checkpoint (``checkpoint.py``)."""
        return mapper_state(self)

    def save_checkpoint(self, path: str | Path) -> None:
        """Write ``map.npz``: the Gaussians plus the mapper state needed to resume, and the memory views it
        does not have on disk yet (``checkpoint.write_checkpoint``).

        Args:
            path: the ``map.npz`` to write (atomically; its views go to ``map_memory/`` beside it).
        """
        write_checkpoint(self, path)

    def load_checkpoint(self, path: str | Path) -> None:
        """Restore the map and mapper state from ``map.npz`` (written by ``save``/``save_checkpoint``, by
        this version or, upgraded by ``checkpoint.upgrade``, an older one).

        Args:
            path: the ``map.npz`` to read.

        Raises:
            DataError: unreadable, damaged, from a newer version, or not a mapper checkpoint.
        """
        p = Path(path)
        self.map = GaussianMap.load_npz(p, self.device)
        restore_mapper(self, read_checkpoint(p, self.config.seed), p)

    def save(self, out_dir: str | Path) -> Path:
        """Write the run directory ``out_dir``: config.yaml and map.npz (with its memory views in
        map_memory/) first, which is what a resume needs, then the exports: gaussians.ply, timings.json, under
        odometry traj.txt (the tracked poses, one row-major c2w 4x4 per frame read) and graph.json. A save cut
        short (a full disk) thus leaves a map that ``run --resume`` writes the exports from. Saved outside a
        run that records its id (``source["run_id"]``), an earlier run's ``run_id`` file there is removed. The
        run folder's files and their order are :func:`ogscene3d.runs.save_run`'s.

        Args:
            out_dir: the run folder (created when missing).

        Returns:
            The run folder's path.

        Raises:
            SaveError: a write failed; it names the file and those written before it.
        """
        return save_run(
            out_dir,
            config=self.config,
            checkpoint=self.save_checkpoint,
            gaussians=self.map.export_ply,
            timings=lambda: self.timings.document(self.cfg.ablation, self.finalized),
            trajectory=self._trajectory_text,
            graph=lambda: self.graph_feed.document(self.map, self.keyframe_count),
            keeps_run_id="run_id" in self.source,
        )

    def _trajectory_text(self) -> str | None:
        filled = hold_last_good(self.trajectory)  # as `ogscene3d track` writes it: one pose per frame read
        return trajectory_text(filled) if filled else None
