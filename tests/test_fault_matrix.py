"""A fast slice of benchmarks/fault_matrix.py (the whole matrix takes minutes): the dataset faults of #31
through the CLI, so that the script itself keeps working and these rows keep passing."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

SCRIPT = Path(__file__).resolve().parents[1] / "benchmarks" / "fault_matrix.py"


def test_fault_matrix_dataset_rows_pass(tmp_path):
    only = ["traj line short", "rgb missing", "cam_params wrong width"]
    args = [sys.executable, str(SCRIPT), "--keep", str(tmp_path)]
    for o in only:
        args += ["--only", o]
    proc = subprocess.run(args, capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    assert "5 passed, 0 failed" in proc.stdout
    for row in ("frame: traj line short [skip]", "frame: rgb missing [error]", "cam_params wrong width"):
        assert any(row in line and " pass " in line for line in proc.stdout.splitlines()), row
