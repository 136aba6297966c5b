"""Launch arguments: the bare Warp array descriptors render.py builds from torch tensors."""

from __future__ import annotations

import pytest
import torch

from ogscene3d import render
from ogscene3d.device import init_warp

wp = init_warp()


def _fields(arg) -> tuple:
    return arg.data, arg.grad, arg.ndim, arg.shape[0], arg.strides[0]


@pytest.mark.parametrize(
    "tensor,dtype,count,stride",
    [
        (torch.zeros(5, 3), wp.vec3, 5, 12),
        (torch.zeros(2, 4, 3), wp.vec3, 8, 12),
        (torch.zeros(6, 3, 3), wp.mat33, 6, 36),
        (torch.zeros(7, dtype=torch.int32), None, 7, 4),
        (torch.zeros(7), wp.float32, 7, 4),
        (torch.zeros(3, 8, dtype=torch.int32), wp.types.vector(length=8, dtype=wp.int32), 3, 32),
        (torch.zeros(4, dtype=torch.uint8), None, 4, 1),
    ],
)
def test_descriptor_matches_from_torch(tensor, dtype, count, stride, monkeypatch) -> None:
    arg = render._as_wp(tensor, dtype)
    assert _fields(arg)[2:] == (1, count, stride)
    assert arg.data == arg.tensor.data_ptr() and arg.tensor.is_contiguous()
    monkeypatch.setattr(render, "_array_descriptor", lambda: None)  # the wp.from_torch path
    assert _fields(render._as_wp(tensor, dtype))[1:] == _fields(arg)[1:]


def test_non_contiguous_tensor_is_copied() -> None:
    t = torch.arange(12, dtype=torch.float32).reshape(3, 4).t()
    arg = render._as_wp(t)
    assert arg.tensor.is_contiguous() and torch.equal(arg.tensor, t)


@pytest.mark.parametrize(
    "tensor,dtype",
    [
        (torch.zeros(3, dtype=torch.float64), None),
        (torch.zeros(3, 2), wp.vec2i),
        (torch.zeros(3), wp.int32),
        (torch.zeros(4, 4), wp.vec3),
        (torch.zeros(3, 9), wp.mat33),
    ],
)
def test_mismatched_dtype_is_refused(tensor, dtype) -> None:
    with pytest.raises(TypeError, match="cannot pass|trailing dims"):
        render._as_wp(tensor, dtype)
