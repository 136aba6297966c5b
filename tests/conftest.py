import os
import sys
from pathlib import Path

import pytest
import torch

ROOT = Path(__file__).resolve().parents[1]
SHARED_DATA = Path(os.environ.get("OGSCENE3D_SHARED_DATA", ROOT.parent / "shared" / "data"))


def _devices() -> list[str]:
    devs = ["cpu"]
    if torch.cuda.is_available():
        devs.append("cuda")
    return devs


DEVICES = _devices()


@pytest.fixture(params=DEVICES)
def device(request) -> str:
    """Every kernel test body runs once per available device (cpu always, cuda when present)."""
    return request.param


@pytest.fixture
def shared_data() -> Path:
    if not SHARED_DATA.is_dir():
        pytest.skip(f"shared sample data not found at {SHARED_DATA}")
    return SHARED_DATA


# the helpers that tests share (scenes, file writers, reference implementations), imported by module name
sys.path.insert(0, str(ROOT / "tests" / "helpers"))


@pytest.fixture
def stop_after_frame(monkeypatch):
    """``stop_after_frame(index, send)``: Mapper.process calls ``send()`` (a Ctrl-C, a SIGTERM) right after
    mapping frame ``index``; returns the unpatched process, for a test that goes on without the stop."""
    from ogscene3d.mapping.mapper import Mapper

    process = Mapper.process

    def patch(index: int, send):
        def stopped(self, frame):
            kept = process(self, frame)
            if frame.index == index:
                send()
            return kept

        monkeypatch.setattr(Mapper, "process", stopped)
        return process

    return patch
