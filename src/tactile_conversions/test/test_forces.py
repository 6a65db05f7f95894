import numpy as np
import pytest
from builtin_interfaces.msg import Time
from visualization_msgs.msg import Marker

from tactile_conversions.forces import force_distribution_msg, force_markers, forces_from_msg, wrench_msg
from tactile_description import FORCE_COMPONENTS, load_sensor


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
    msg = force_distribution_msg(forces, grid, Time(sec=7), "tactile_surface", ["cam0", "cam1"], ["cam2"],
                                 FORCE_COMPONENTS)
    flat = np.asarray(msg.forces_n)
    assert flat.size == grid.rows * grid.cols * 3
    assert flat[(3 * grid.cols + 7) * 3 + 2] == pytest.approx(0.3)
    np.testing.assert_array_equal(flat.reshape(msg.rows, msg.cols, 3), forces)
    assert (msg.total_force_n.x, msg.total_force_n.y, msg.total_force_n.z) == pytest.approx((0.01, -0.02, 0.35))
    assert msg.bin_size_x_m == pytest.approx(grid.bin_width_m)
    assert list(msg.camera_ids) == ["cam0", "cam1"] and list(msg.missing_camera_ids) == ["cam2"]
    assert msg.header.stamp.sec == 7 and msg.header.frame_id == "tactile_surface"
    assert list(msg.estimated_components) == ["fx", "fy", "fz"]


def test_a_received_distribution_is_read_back_or_refused_naming_what_is_wrong(grid):
    forces = loaded_bins(grid)
    msg = force_distribution_msg(forces, grid, Time(sec=7), "tactile_surface", ["cam0"], [], FORCE_COMPONENTS)
    np.testing.assert_array_equal(forces_from_msg(msg, grid), forces)
    assert forces_from_msg(msg, grid).dtype == np.float64
    msg.forces_n = msg.forces_n[:10]
    with pytest.raises(ValueError, match=r"26 x 25 bins and 10 values, where the sensor description has 26 x 25 bins "
                                         r"\(1950 values\)"):
        forces_from_msg(msg, grid)
    msg = force_distribution_msg(forces, grid, Time(sec=7), "tactile_surface", ["cam0"], [], FORCE_COMPONENTS)
    msg.rows, msg.cols = 25, 26
    with pytest.raises(ValueError, match="25 x 26 bins and 1950 values"):
        forces_from_msg(msg, grid)
    msg = force_distribution_msg(forces, grid, Time(sec=7), "tactile_surface", ["cam0"], [], FORCE_COMPONENTS)
    msg.forces_n[4] = float("nan")
    with pytest.raises(ValueError, match="NaN or Inf among its forces"):
        forces_from_msg(msg, grid)


def test_components_not_estimated_are_named_and_must_be_zero(grid):
    vertical = loaded_bins(grid)
    vertical[..., :2] = 0.0
    msg = force_distribution_msg(vertical, grid, Time(), "f", [], [], ("fz",))
    assert list(msg.estimated_components) == ["fz"]
    with pytest.raises(ValueError, match=r"\['fx', 'fy'\] are not estimated but hold forces"):
        force_distribution_msg(loaded_bins(grid), grid, Time(), "f", [], [], ("fz",))
    for wrong in [(), ("fz", "fx"), ("fz", "fz"), ("torque",)]:
        with pytest.raises(ValueError, match="estimated components must be distinct names"):
            force_distribution_msg(vertical, grid, Time(), "f", [], [], wrong)


def test_wrench_is_the_applied_total_force_as_a_vector_in_the_surface_frame(grid):
    """Pressing (fz > 0 in compression) pushes along -z; fx and fy keep their direction, as the markers draw them."""
    msg = force_distribution_msg(loaded_bins(grid), grid, Time(sec=3), "tactile_surface", [], [], FORCE_COMPONENTS)
    wrench = wrench_msg(msg)
    force = wrench.wrench.force
    assert (force.x, force.y, force.z) == pytest.approx((0.01, -0.02, -0.35))
    markers = force_markers(loaded_bins(grid), grid, Time(sec=3), "tactile_surface").markers[0]
    tail, head = markers.points[0], markers.points[1]  # bin (3, 7): (0.01, -0.02, 0.3) N
    assert np.sign([head.x - tail.x, head.y - tail.y, head.z - tail.z]).tolist() == [1, -1, -1]
    torque = wrench.wrench.torque
    assert (torque.x, torque.y, torque.z) == (0.0, 0.0, 0.0)
    assert wrench.header.stamp.sec == 3 and wrench.header.frame_id == "tactile_surface"


def test_non_finite_or_misshapen_forces_are_never_published(grid):
    forces = loaded_bins(grid)
    forces[0, 0, 0] = np.nan
    with pytest.raises(FloatingPointError):
        force_distribution_msg(forces, grid, Time(), "f", [], [], FORCE_COMPONENTS)
    with pytest.raises(ValueError, match="shape"):
        force_distribution_msg(np.zeros((3, 3, 3)), grid, Time(), "f", [], [], FORCE_COMPONENTS)
    huge = loaded_bins(grid).astype(np.float64)
    huge[1, 1, 2] = 1e39  # finite in float64, Inf in the message's float32
    with pytest.raises(FloatingPointError):
        force_distribution_msg(huge, grid, Time(), "f", [], [], FORCE_COMPONENTS)


def test_markers_are_one_line_per_loaded_bin_into_the_gel(grid):
    markers = force_markers(loaded_bins(grid), grid, Time(), "tactile_surface").markers
    assert len(markers) == 1
    lines = markers[0]
    assert (lines.type, lines.action) == (Marker.LINE_LIST, Marker.ADD) and lines.color.a == 1.0
    assert len(lines.points) == len(lines.colors) == 4
    centre = grid.bin_centers_m()[3, 7]
    strongest = next(i for i in (0, 2) if lines.points[i].x == pytest.approx(centre[0])
                     and lines.points[i].y == pytest.approx(centre[1]))
    tail, head = lines.points[strongest:strongest + 2]
    assert head.z == pytest.approx(-0.3 / 5.0) and tail.z == 0.0
    assert (head.x - tail.x, head.y - tail.y) == pytest.approx((0.01 / 5.0, -0.02 / 5.0))
    assert lines.colors[strongest].r == pytest.approx(1.0) and lines.colors[strongest].b == pytest.approx(0.0)
    assert lines.colors[2 - strongest].r < 0.2


def test_every_bin_loaded_gives_every_line(grid):
    forces = np.full((grid.rows, grid.cols, 3), 0.01)
    lines = force_markers(forces, grid, Time(), "tactile_surface").markers[0]
    assert len(lines.points) == len(lines.colors) == 2 * grid.rows * grid.cols


def test_no_load_deletes_the_lines(grid):
    empty = np.zeros((grid.rows, grid.cols, 3))
    markers = force_markers(empty, grid, Time(), "tactile_surface").markers
    assert len(markers) == 1 and markers[0].action == Marker.DELETE and not markers[0].points


def test_lines_live_as_long_as_asked(grid):
    lines = force_markers(loaded_bins(grid), grid, Time(), "tactile_surface", lifetime_s=2.5).markers[0]
    assert (lines.lifetime.sec, lines.lifetime.nanosec) == (2, 500_000_000)
    lines = force_markers(loaded_bins(grid), grid, Time(), "tactile_surface", lifetime_s=1.9999999999).markers[0]
    assert (lines.lifetime.sec, lines.lifetime.nanosec) == (2, 0)


def test_non_finite_or_misshapen_forces_and_bad_scales_are_never_drawn(grid):
    forces = loaded_bins(grid)
    forces[5, 5, 2] = np.inf
    with pytest.raises(FloatingPointError):
        force_markers(forces, grid, Time(), "tactile_surface")
    with pytest.raises(ValueError, match="shape"):
        force_markers(np.zeros((grid.cols, grid.rows, 3)), grid, Time(), "tactile_surface")
    # 1e200 N overflowed the magnitudes (an IndexError), 1e-320 N/m drew a line to Inf, 3e9 s wrapped round the
    # lifetime's int32 seconds and 4e-10 s rounded to 0 ns, RViz's "forever" (review)
    forces = loaded_bins(grid).astype(np.float64)
    forces[5, 5, 2] = 1e200
    with pytest.raises(FloatingPointError):
        force_markers(forces, grid, Time(), "tactile_surface")
    for bad in ({"newtons_per_metre": 0.0}, {"newtons_per_metre": 1e-320}, {"min_force_n": 0.0},
                {"lifetime_s": 0.0}, {"lifetime_s": np.nan}, {"lifetime_s": np.inf}, {"lifetime_s": 3e9},
                {"lifetime_s": 4e-10}):
        with pytest.raises(ValueError, match=r"need newtons_per_metre in \[1e-09, 1e\+09\], min_force_n > 0 and "
                                             r"lifetime_s in \[0.001, 1e\+07\] s"):
            force_markers(loaded_bins(grid), grid, Time(), "tactile_surface", **bad)
    longest = force_markers(loaded_bins(grid), grid, Time(), "tactile_surface", lifetime_s=1e7).markers[0].lifetime
    assert (longest.sec, longest.nanosec) == (10_000_000, 0)
