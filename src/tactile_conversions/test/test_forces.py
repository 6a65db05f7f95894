import numpy as np
import pytest
from builtin_interfaces.msg import Time
from visualization_msgs.msg import Marker

from tactile_conversions.forces import force_distribution_msg, force_markers, wrench_msg
from tactile_description import load_sensor


@pytest.fixture(scope="module")
def grid():
    return load_sensor().grid


def loaded_bins(grid):
    forces = np.zeros((grid.rows, grid.cols, 3), np.float32)
    forces[3, 7] = (0.01, -0.02, 0.3)
    forces[20, 1] = (0.0, 0.0, 0.05)
    return forces


def test_layout_is_row_major_with_components_innermost(grid):
    forces = loaded_bins(grid)
    msg = force_distribution_msg(forces, grid, Time(sec=7), "tactile_surface", ["cam0", "cam1"], ["cam2"])
    flat = np.asarray(msg.forces_n)
    assert flat.size == grid.rows * grid.cols * 3
    assert flat[(3 * grid.cols + 7) * 3 + 2] == pytest.approx(0.3)
    np.testing.assert_array_equal(flat.reshape(msg.rows, msg.cols, 3), forces)
    assert (msg.total_force_n.x, msg.total_force_n.y, msg.total_force_n.z) == pytest.approx((0.01, -0.02, 0.35))
    assert msg.bin_size_x_m == pytest.approx(grid.bin_width_m)
    assert list(msg.camera_ids) == ["cam0", "cam1"] and list(msg.missing_camera_ids) == ["cam2"]
    assert msg.header.stamp.sec == 7 and msg.header.frame_id == "tactile_surface"


def test_wrench_carries_the_total_force_and_stamp(grid):
    msg = force_distribution_msg(loaded_bins(grid), grid, Time(sec=3), "tactile_surface", [], [])
    wrench = wrench_msg(msg)
    assert wrench.wrench.force.z == pytest.approx(0.35)
    assert wrench.header.stamp.sec == 3


def test_non_finite_or_misshapen_forces_are_never_published(grid):
    forces = loaded_bins(grid)
    forces[0, 0, 0] = np.nan
    with pytest.raises(FloatingPointError):
        force_distribution_msg(forces, grid, Time(), "f", [], [])
    with pytest.raises(ValueError, match="shape"):
        force_distribution_msg(np.zeros((3, 3, 3)), grid, Time(), "f", [], [])


def test_markers_point_into_the_gel_for_a_press(grid):
    markers = force_markers(loaded_bins(grid), grid, Time(), "tactile_surface").markers
    assert markers[0].action == Marker.DELETEALL
    arrows = markers[1:]
    assert len(arrows) == 2
    strongest = next(m for m in arrows if m.id == 3 * grid.cols + 7)
    tail, head = strongest.points
    assert head.z < tail.z == 0.0
    assert strongest.color.r == pytest.approx(1.0)


def test_no_arrows_without_load(grid):
    empty = np.zeros((grid.rows, grid.cols, 3))
    assert len(force_markers(empty, grid, Time(), "tactile_surface").markers) == 1


def test_arrows_live_as_long_as_asked(grid):
    arrows = force_markers(loaded_bins(grid), grid, Time(), "tactile_surface", lifetime_s=2.5).markers[1:]
    assert all((a.lifetime.sec, a.lifetime.nanosec) == (2, 500_000_000) for a in arrows)
