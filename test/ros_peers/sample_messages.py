"""Deterministic ForceDistribution and ImageBundle messages, and a field-by-field dump to compare them.

Shared by the two peer processes of the DDS round-trip test and by the test itself, so that every field of
both messages is filled with a value that would be noticed if it were lost or altered on the way.
"""

from __future__ import annotations

import array

import numpy as np
from builtin_interfaces.msg import Time
from geometry_msgs.msg import Vector3
from sensor_msgs.msg import Image
from std_msgs.msg import Header

from tactile_msgs.msg import ForceDistribution, ImageBundle

ROWS, COLS = 26, 25
CAMERA_IDS = ["cam0", "cam1", "cam2", "cam3"]


def force_distribution() -> ForceDistribution:
    rng = np.random.default_rng(650)
    forces = rng.normal(0.0, 0.01, (ROWS, COLS, 3)).astype(np.float32)
    forces[..., 2] = np.abs(forces[..., 2])
    total = forces.astype(np.float64).sum(axis=(0, 1))
    msg = ForceDistribution()
    msg.header = Header(stamp=Time(sec=1_763_700_000, nanosec=123_456_789), frame_id="tactile_surface")
    msg.rows, msg.cols = ROWS, COLS
    msg.bin_size_x_m, msg.bin_size_y_m = 0.00196, 0.0019615384615384616
    msg.forces_n = array.array("f", forces.ravel().tobytes())
    msg.total_force_n = Vector3(x=float(total[0]), y=float(total[1]), z=float(total[2]))
    msg.camera_ids = CAMERA_IDS[:3]
    msg.missing_camera_ids = CAMERA_IDS[3:]
    msg.estimated_components = ["fx", "fy", "fz"]
    return msg


def image_bundle() -> ImageBundle:
    rng = np.random.default_rng(128)
    msg = ImageBundle()
    msg.header = Header(stamp=Time(sec=1_763_700_000, nanosec=25_000_000), frame_id="tactile_surface")
    msg.sequence = 2**40 + 7  # beyond 32 bits
    msg.camera_ids = CAMERA_IDS
    for i, camera_id in enumerate(CAMERA_IDS):
        pixels = rng.integers(0, 256, (128, 128), dtype=np.uint8)
        image = Image(header=Header(stamp=Time(sec=1_763_700_000, nanosec=25_000_000 + 1_000_000 * i),
                                    frame_id=f"{camera_id}_optical"),
                      height=128, width=128, encoding="mono8", is_bigendian=0, step=128)
        image.data = pixels.tobytes()
        msg.images.append(image)
    msg.max_stamp_spread_s = 0.003
    return msg


def to_plain(value):
    """A message as nested dicts/lists of plain Python values (JSON-safe), field by field."""
    if hasattr(value, "get_fields_and_field_types"):
        return {name: to_plain(getattr(value, name)) for name in value.get_fields_and_field_types()}
    if isinstance(value, (list, tuple)):
        return [to_plain(v) for v in value]
    if isinstance(value, array.array):
        return value.tolist()
    if isinstance(value, (bytes, bytearray)):
        return list(value)
    if isinstance(value, np.ndarray):
        return value.tolist()
    return value
