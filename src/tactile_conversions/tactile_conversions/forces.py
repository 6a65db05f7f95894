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

from tactile_description import FORCE_COMPONENTS, BinGrid, left_out_components
from tactile_msgs.msg import ForceDistribution


def checked_forces(bin_forces_n: np.ndarray, grid: BinGrid, dtype: type = np.float64) -> np.ndarray:
    """The forces as `dtype` if they have the grid's shape (rows, cols, 3) and are finite in it; else ValueError or
    FloatingPointError (nothing non-finite is published or drawn: a float64 above 3.4e38 is Inf in float32)."""
    with np.errstate(over="ignore"):  # an overflow to Inf is reported below
        forces = np.asarray(bin_forces_n, dtype=dtype)
    if forces.shape != (grid.rows, grid.cols, 3):
        raise ValueError(f"bin forces have shape {forces.shape}, the grid needs ({grid.rows}, {grid.cols}, 3)")
    if not np.isfinite(forces).all():
        raise FloatingPointError("refusing to publish non-finite bin forces")
    return forces


def forces_from_msg(msg: ForceDistribution, grid: BinGrid) -> np.ndarray:
    """The (rows, cols, 3) float64 forces of a received ForceDistribution of `grid`; ValueError naming what is wrong:
    another grid, a value count that does not fill it, or a NaN or Inf among them. For the subscribers that compare
    messages with the sensor description (tactile-demo, tactile-bag eval)."""
    rows, cols = grid.rows, grid.cols
    if (msg.rows, msg.cols) != (rows, cols) or len(msg.forces_n) != rows * cols * 3:
        raise ValueError(f"{msg.rows} x {msg.cols} bins and {len(msg.forces_n)} values, where the sensor description "
                         f"has {rows} x {cols} bins ({rows * cols * 3} values)")
    try:
        return checked_forces(np.asarray(msg.forces_n).reshape(rows, cols, 3), grid)
    except FloatingPointError as exc:  # of a received message: its data, not this process's arithmetic, is wrong
        raise ValueError("NaN or Inf among its forces") from exc


def force_distribution_msg(bin_forces_n: np.ndarray, grid: BinGrid, stamp: Time, frame_id: str,
                           camera_ids: Sequence[str], missing_camera_ids: Sequence[str],
                           estimated_components: Sequence[str]) -> ForceDistribution:
    """The message for forces of shape (rows, cols, 3) in newtons (fz positive in compression), of which
    `estimated_components` (of FORCE_COMPONENTS, in that order) carry an estimate and the others are zero."""
    forces = checked_forces(bin_forces_n, grid, np.float32)
    problem = components_problem(forces, estimated_components)
    if problem:
        raise ValueError(problem)
    total = forces.astype(np.float64).sum(axis=(0, 1))
    msg = ForceDistribution(header=Header(stamp=stamp, frame_id=frame_id), rows=grid.rows, cols=grid.cols,
                            bin_size_x_m=grid.bin_width_m, bin_size_y_m=grid.bin_length_m,
                            total_force_n=Vector3(x=float(total[0]), y=float(total[1]), z=float(total[2])),
                            camera_ids=list(camera_ids), missing_camera_ids=list(missing_camera_ids),
                            estimated_components=list(estimated_components))
    msg.forces_n = array.array("f", forces.tobytes())
    return msg


def components_problem(forces: np.ndarray, estimated_components: Sequence[str]) -> str | None:
    """What is wrong with `estimated_components` as the `estimated_components` of forces (rows, cols, 3), or None: they
    must be distinct names of FORCE_COMPONENTS in that order, and the components left out must be zero."""
    estimated = list(estimated_components)
    if not estimated or estimated != [c for c in FORCE_COMPONENTS if c in estimated]:
        return f"estimated components must be distinct names of {list(FORCE_COMPONENTS)} in that order, got {estimated}"
    left_out = left_out_components(estimated)
    if np.asarray(forces)[..., [FORCE_COMPONENTS.index(c) for c in left_out]].any():
        return f"components {list(left_out)} are not estimated but hold forces"
    return None


def wrench_msg(distribution: ForceDistribution) -> WrenchStamped:
    """The total force the object applies to the surface as a WrenchStamped: a vector in the surface frame, so z is
    -total fz (negative when pressing; ForceDistribution counts fz positive in compression), x and y are the total
    fx and fy. A wrench is a vector that tf rotates and RViz draws as it is: with z as ForceDistribution's, its arrow
    pointed out of the surface while the bin markers point into the gel. Torque is not estimated: zero."""
    total = distribution.total_force_n
    return WrenchStamped(header=distribution.header, wrench=Wrench(force=Vector3(x=total.x, y=total.y, z=-total.z)))


#: The markers' namespace (config/tactile.rviz enables it by name).
MARKER_NAMESPACE = "bin_forces"
#: The scales force_markers takes, newtons drawn as a metre, and how long RViz shows a marker (s): beyond them a line's
#: end overflowed to Inf (1e-320 N/m), a lifetime wrapped round Duration's int32 seconds (3e9 s) or rounded to 0 ns,
#: which RViz reads as "forever" (review).
NEWTONS_PER_METRE_RANGE = (1e-9, 1e9)
MARKER_LIFETIME_RANGE_S = (1e-3, 1e7)
#: Colour levels of the force lines, blue (weak) to red (the strongest bin). The ColorRGBA objects are shared by
#: every marker built here (building 1300 of them per marker costs more than the rest): do not edit them in place.
COLOUR_LEVELS = 64
_PALETTE = tuple(ColorRGBA(r=level, g=0.2 * (1.0 - level), b=1.0 - level, a=1.0)
                 for level in np.linspace(0.0, 1.0, COLOUR_LEVELS).tolist())


def force_markers(bin_forces_n: np.ndarray, grid: BinGrid, stamp: Time, frame_id: str,
                  newtons_per_metre: float = 5.0, min_force_n: float = 1e-3, lifetime_s: float = 1.0) -> MarkerArray:
    """One LINE_LIST marker: a line per loaded bin, from the surface into the gel along the applied force.

    Lines are scaled so that `newtons_per_metre` newtons draw one metre (the default draws 50 mN, a firmly
    loaded bin of the reference sensor, as 1 cm) and coloured by |F| relative to the strongest bin. Bins below
    `min_force_n` (> 0) get no line; without any, the marker is deleted. RViz drops the lines `lifetime_s` after
    their estimate, so that a stopped node leaves no stale picture: it must outlast the time between two markers.

    One marker for all bins rather than an arrow marker per bin: building and serialising 650 arrows in Python
    took about 40 ms with every bin loaded, more than a 40 Hz frame (docs/nodes.md has the figures).
    """
    if not (NEWTONS_PER_METRE_RANGE[0] <= newtons_per_metre <= NEWTONS_PER_METRE_RANGE[1] and min_force_n > 0
            and MARKER_LIFETIME_RANGE_S[0] <= lifetime_s <= MARKER_LIFETIME_RANGE_S[1]):
        raise ValueError(f"need newtons_per_metre in [{NEWTONS_PER_METRE_RANGE[0]:g}, {NEWTONS_PER_METRE_RANGE[1]:g}], "
                         f"min_force_n > 0 and lifetime_s in [{MARKER_LIFETIME_RANGE_S[0]:g}, "
                         f"{MARKER_LIFETIME_RANGE_S[1]:g}] s, got {newtons_per_metre}, {min_force_n}, {lifetime_s}")
    # As a ForceDistribution carries them, float32: a force of 1e200 N overflowed the magnitudes to Inf (review)
    forces = checked_forces(bin_forces_n, grid, np.float32).astype(np.float64)
    magnitudes = np.linalg.norm(forces, axis=-1)
    loaded = magnitudes >= min_force_n
    lifetime_ns = round(lifetime_s * 1e9)
    # color: the lines take the per-point colours; an opaque marker colour keeps RViz from blending them.
    marker = Marker(header=Header(stamp=stamp, frame_id=frame_id), ns=MARKER_NAMESPACE, id=0, type=Marker.LINE_LIST,
                    action=Marker.ADD if loaded.any() else Marker.DELETE,
                    scale=Vector3(x=0.2 * grid.bin_width_m), color=ColorRGBA(r=1.0, g=1.0, b=1.0, a=1.0),
                    lifetime=Duration(sec=lifetime_ns // 1_000_000_000, nanosec=lifetime_ns % 1_000_000_000))
    if marker.action == Marker.DELETE:
        return MarkerArray(markers=[marker])
    centres = grid.bin_centers_m()[loaded]
    # The applied load points into the gel (-z) for fz > 0 (compression), along +x/+y for fx/fy.
    heads = np.column_stack([centres + forces[loaded, :2] / newtons_per_metre,
                             -forces[loaded, 2] / newtons_per_metre])
    tails = np.column_stack([centres, np.zeros(len(centres))])
    ends = np.stack([tails, heads], axis=1).reshape(-1, 3).tolist()
    marker.points = [Point(x=x, y=y, z=z) for x, y, z in ends]
    levels = np.rint(magnitudes[loaded] / magnitudes.max() * (COLOUR_LEVELS - 1)).astype(int).tolist()
    marker.colors = [_PALETTE[level] for level in levels for _ in range(2)]
    return MarkerArray(markers=[marker])
