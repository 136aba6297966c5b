import numpy as np
import pytest

from ogscene3d.frame import implausible_median_depth


@pytest.mark.parametrize(
    "metres, flagged",
    [(0.4, False), (3.0, False), (12.0, False), (0.02, True), (35.0, True), (2000.0, True)],
)
def test_implausible_median_depth(metres, flagged):
    """A shelf at 0.4 m and a hall at 12 m are plausible; millimetres, or label-fusion's bit-shifted depth
    read as linear (about 35 m), are not."""
    depth = np.zeros((8, 8), np.float32)
    depth[2:, :] = metres  # zeros (invalid) do not count
    got = implausible_median_depth(depth)
    assert (got is not None) == flagged
    if flagged:
        assert got == pytest.approx(metres)


def test_no_valid_depth_is_not_judged():
    assert implausible_median_depth(np.zeros((4, 4), np.float32)) is None
