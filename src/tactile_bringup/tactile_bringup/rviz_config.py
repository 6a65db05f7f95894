"""The RViz configuration of a sensor: its bin grid, the force markers and the total force, in its frame.

`sensor.launch.py rviz:=true` writes it for the sensor description it runs (`write_rviz_config` without a path), so
that a sensor with another `frame_id` or other bins is shown as it is (with one fixed configuration, RViz showed
nothing for a sensor in another frame). `config/tactile.rviz` is this configuration for the reference sensor, to open
without the launch system (`rviz2 -d config/tactile.rviz`); a test keeps the two equal.
"""

from __future__ import annotations

import hashlib
import math
import os
import tempfile
from pathlib import Path

import yaml

from tactile_conversions.forces import MARKER_NAMESPACE
from tactile_conversions.topics import MARKERS_TOPIC, ROOT_NAMESPACE, WRENCH_TOPIC, in_namespace
from tactile_description import SensorDescription

#: RViz draws the total force at this many metres per newton (1 N as 1 cm; the lines of the bins: 50 mN as 1 cm).
WRENCH_ARROW_M_PER_N = 0.01


def _topic(name: str) -> dict:
    """A display's subscription: the fusion node publishes markers and wrench reliably, keeping the last few."""
    return {"Value": name, "Depth": 5, "Durability Policy": "Volatile", "History Policy": "Keep Last",
            "Reliability Policy": "Reliable"}


def grid_display(sensor: SensorDescription) -> dict:
    """RViz's Grid of square cells, one per bin, its lines on the bins' edges from the surface's corner at (0, 0).

    RViz draws a Grid's lines at offset - count * size / 2 + i * size, i = 0..count (rviz_rendering's
    Grid::createGridPlane), in both directions alike: with the offset at count * size / 2 they start at 0. The cells
    are as wide as a bin, and as many each way as cover the surface's longer side: where bins are not square, the lines
    across x fall on the bins' edges and those across y do not (the reference sensor's bins are 1.96 mm along x and
    1.96 mm along y, to 2 um). A count of the bins along the longer side left most of a surface of long narrow bins
    uncovered (review); a side that a whole number of cells misses by under a twentieth of a cell takes no more.
    """
    grid = sensor.grid
    size = grid.bin_width_m
    count = max(grid.cols, math.ceil(max(grid.width_m, grid.length_m) / size - 0.05))
    half = round(count * size / 2, 9)
    return {"Class": "rviz_default_plugins/Grid", "Name": f"Surface bins ({size * 1e3:.3g} mm)", "Enabled": True,
            "Reference Frame": "<Fixed Frame>", "Plane": "XY", "Cell Size": round(size, 9),
            "Plane Cell Count": count, "Offset": {"X": half, "Y": half, "Z": 0}, "Color": "160; 160; 164",
            "Alpha": 0.5}


def rviz_config(sensor: SensorDescription, namespace: str = ROOT_NAMESPACE) -> dict:
    """The configuration as the mapping RViz reads from a .rviz file, for the sensor graph in `namespace` ("left" or
    "/left", see tactile_conversions.topics.graph_namespace)."""
    centre_x, centre_y = sensor.grid.centre_m
    extent = max(sensor.grid.width_m, sensor.grid.length_m)
    displays = [
        grid_display(sensor),
        {"Class": "rviz_default_plugins/MarkerArray", "Name": "Bin forces", "Enabled": True,
         "Topic": _topic(in_namespace(MARKERS_TOPIC, namespace)), "Namespaces": {MARKER_NAMESPACE: True}},
        {"Class": "rviz_default_plugins/Wrench", "Name": "Total force", "Enabled": True,
         "Topic": _topic(in_namespace(WRENCH_TOPIC, namespace)), "Force Arrow Scale": WRENCH_ARROW_M_PER_N,
         "Force Color": "204; 51; 51", "Torque Arrow Scale": 0},
    ]
    view = {"Class": "rviz_default_plugins/Orbit", "Name": "Current View", "Target Frame": "<Fixed Frame>",
            "Focal Point": {"X": round(centre_x, 9), "Y": round(centre_y, 9), "Z": 0},
            "Distance": round(2.4 * extent, 3), "Pitch": 0.9, "Yaw": 4.0}
    return {"Panels": [{"Class": "rviz_common/Displays", "Name": "Displays"}],
            "Visualization Manager": {
                "Class": "", "Displays": displays,
                "Global Options": {"Fixed Frame": sensor.frame_id, "Background Color": "48; 48; 48",
                                   "Frame Rate": 30},
                "Tools": [{"Class": "rviz_default_plugins/MoveCamera"}],
                "Views": {"Current": view}}}


def write_rviz_config(sensor: SensorDescription, path: str | Path | None = None,
                      namespace: str = ROOT_NAMESPACE) -> Path:
    """Write `rviz_config(sensor, namespace)` to `path` (a .rviz file); returns the path.

    Without a path, to the file that sensor.launch.py gives RViz: `$ROS_HOME/tactile_bringup/rviz_<digest>.rviz`
    (ROS_HOME defaults to ~/.ros, where ROS keeps its logs), named by a digest of the configuration, so that every
    launch of a sensor description writes the same file again and two launches of different sensors (or namespaces)
    do not share one.
    A temporary directory per launch (before 2026-11-27) left one behind at every launch. Where that folder cannot be
    written (a ROS_HOME that is a file or read-only, no home directory), a new temporary directory takes the file: the
    graph must not fail to start for RViz's sake (review)."""
    text = yaml.safe_dump(rviz_config(sensor, namespace), sort_keys=False)
    if path is not None:
        return _replace_file(Path(path), text)
    name = f"rviz_{hashlib.sha256(text.encode()).hexdigest()[:16]}.rviz"
    try:
        folder = Path(os.environ.get("ROS_HOME") or Path.home() / ".ros").expanduser().resolve() / "tactile_bringup"
        folder.mkdir(parents=True, exist_ok=True)
        return _replace_file(folder / name, text)
    except (OSError, RuntimeError):  # RuntimeError: Path.home() of a user without a home directory
        return _replace_file(Path(tempfile.mkdtemp(prefix="tactile_bringup_")) / name, text)


def _replace_file(path: Path, text: str) -> Path:
    """Write `path` in one step (written beside, then renamed), so that an RViz starting meanwhile never reads half
    of it; nothing is left beside it if that fails."""
    partial = path.with_name(f".{path.name}.{os.getpid()}")
    try:
        partial.write_text(text)
        os.replace(partial, path)
    finally:
        partial.unlink(missing_ok=True)
    return path
