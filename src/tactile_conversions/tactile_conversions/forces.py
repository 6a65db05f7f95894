"""Bin forces (numpy) -> the messages a controller and RViz read: ForceDistribution, WrenchStamped, MarkerArray.

Kept apart from the node so that the layout documented in ForceDistribution.msg is produced (and tested) in one
place. No NaN or Inf leaves here: non-finite forces raise instead of being published.
"""

from __future__ import annotations

import array
from collections.abc import Sequence

import numpy as np
from builtin_interfaces.msg import Duration, Time
from geometry_msgs.msg import Point, Vector3, Wrench, WrenchStamped
from std_msgs.msg import ColorRGBA, Header
from visualization_msgs.msg import Marker, MarkerArray

from tactile_description import BinGrid
from tactile_msgs.msg import ForceDistribution


def force_distribution_msg(bin_forces_n: np.ndarray, grid: BinGrid, stamp: Time, frame_id: str,
                           camera_ids: Sequence[str], missing_camera_ids: Sequence[str]) -> ForceDistribution:
    """The message for forces of shape (rows, cols, 3) in newtons (fz positive in compression)."""
    forces = np.asarray(bin_forces_n, dtype=np.float32)
    if forces.shape != (grid.rows, grid.cols, 3):
        raise ValueError(f"bin forces have shape {forces.shape}, the grid needs ({grid.rows}, {grid.cols}, 3)")
    if not np.isfinite(forces).all():
        raise FloatingPointError("refusing to publish non-finite bin forces")
    total = forces.astype(np.float64).sum(axis=(0, 1))
    msg = ForceDistribution(header=Header(stamp=stamp, frame_id=frame_id), rows=grid.rows, cols=grid.cols,
                            bin_size_x_m=grid.bin_width_m, bin_size_y_m=grid.bin_length_m,
                            total_force_n=Vector3(x=float(total[0]), y=float(total[1]), z=float(total[2])),
                            camera_ids=list(camera_ids), missing_camera_ids=list(missing_camera_ids))
    msg.forces_n = array.array("f", forces.tobytes())
    return msg


def wrench_msg(distribution: ForceDistribution) -> WrenchStamped:
    """The total force as a WrenchStamped in the surface frame (torque not estimated: zero)."""
    return WrenchStamped(header=distribution.header, wrench=Wrench(force=distribution.total_force_n))


def force_markers(bin_forces_n: np.ndarray, grid: BinGrid, stamp: Time, frame_id: str,
                  newtons_per_metre: float = 0.1, min_force_n: float = 1e-3, lifetime_s: float = 1.0) -> MarkerArray:
    """One arrow per loaded bin, from the surface into the gel along the applied force, coloured by |F|.

    Arrows are scaled so that `newtons_per_metre` newtons draw one metre (0.1 N -> 1 m would be huge: the
    default draws 1 mN as 1 cm). Bins below `min_force_n` get no arrow; a DELETEALL marker first clears the
    arrows of the previous estimate. RViz drops an arrow `lifetime_s` after its estimate, so that a stopped
    node leaves no stale picture: it must outlast the time between two marker arrays.
    """
    forces = np.asarray(bin_forces_n, dtype=np.float64)
    header = Header(stamp=stamp, frame_id=frame_id)
    markers = [Marker(header=header, ns="bin_forces", action=Marker.DELETEALL)]
    magnitudes = np.linalg.norm(forces, axis=-1)
    peak = max(float(magnitudes.max()), min_force_n)
    centres = grid.bin_centers_m()
    lifetime = Duration(sec=int(lifetime_s), nanosec=int(round((lifetime_s % 1.0) * 1e9)) % 1_000_000_000)
    for row, col in zip(*np.nonzero(magnitudes >= min_force_n), strict=True):
        fx, fy, fz = forces[row, col]
        x, y = centres[row, col]
        # The applied load points into the gel (-z) for fz > 0 (compression), along +x/+y for fx/fy.
        tail = Point(x=float(x), y=float(y), z=0.0)
        head = Point(x=float(x + fx / newtons_per_metre), y=float(y + fy / newtons_per_metre),
                     z=float(-fz / newtons_per_metre))
        level = magnitudes[row, col] / peak
        markers.append(Marker(header=header, ns="bin_forces", id=int(row * grid.cols + col), type=Marker.ARROW,
                              action=Marker.ADD, points=[tail, head],
                              scale=Vector3(x=0.2 * grid.bin_width_m, y=0.4 * grid.bin_width_m, z=0.0),
                              color=ColorRGBA(r=float(level), g=float(0.2 * (1 - level)), b=float(1 - level), a=1.0),
                              lifetime=lifetime))
    return MarkerArray(markers=markers)
