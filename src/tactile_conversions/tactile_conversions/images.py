"""numpy <-> sensor_msgs/Image for the images of this stack, without cv_bridge.

There is no ROS 2 cv_bridge on PyPI (and the PyPI `cv-bridge` port fails on numpy 2), and the stack only needs
8-bit images, so the conversion is done here with numpy and validated field by field: a message whose size,
step or encoding does not match its data is rejected with an error naming the camera, never silently reshaped.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from builtin_interfaces.msg import Time
from sensor_msgs.msg import Image
from std_msgs.msg import Header

from tactile_description.imaging import FrameError, to_mono8

#: Encodings we accept, with their channel count. Colour images are converted to mono by the consumer.
CHANNELS = {"mono8": 1, "8UC1": 1, "bgr8": 3, "rgb8": 3}


class ImageMessageError(ValueError):
    """A sensor_msgs/Image that cannot be read as the image it claims to be."""


def mono8_to_msg(image: np.ndarray, stamp: Time, frame_id: str) -> Image:
    """A mono8 Image message holding a (H, W) uint8 array, not empty (msg_to_array refuses an empty one)."""
    if not isinstance(image, np.ndarray) or image.dtype != np.uint8 or image.ndim != 2 or image.size == 0:
        raise ImageMessageError(f"{frame_id}: expected a non-empty (H, W) uint8 image, got "
                                f"{getattr(image, 'dtype', type(image).__name__)} {getattr(image, 'shape', '')}")
    height, width = image.shape
    msg = Image(header=Header(stamp=stamp, frame_id=frame_id), height=height, width=width, encoding="mono8",
                is_bigendian=0, step=width)
    msg.data = np.ascontiguousarray(image).tobytes()
    return msg


def msg_to_array(msg: Image, camera_id: str) -> np.ndarray:
    """The pixels of an 8-bit Image message as (H, W) or (H, W, 3) uint8, honouring `step` (row padding)."""
    channels = CHANNELS.get(msg.encoding)
    if channels is None:
        raise ImageMessageError(f"{camera_id}: unsupported encoding {msg.encoding!r}; expected one of "
                                f"{sorted(CHANNELS)}")
    row_bytes = msg.width * channels
    if msg.height == 0 or msg.width == 0:
        raise ImageMessageError(f"{camera_id}: empty image ({msg.width} x {msg.height})")
    if msg.step < row_bytes:
        raise ImageMessageError(f"{camera_id}: step {msg.step} is shorter than a row of {row_bytes} bytes")
    if len(msg.data) != msg.step * msg.height:
        raise ImageMessageError(f"{camera_id}: {len(msg.data)} data bytes, but step x height = "
                                f"{msg.step} x {msg.height} = {msg.step * msg.height}")
    rows = np.frombuffer(bytes(msg.data), dtype=np.uint8).reshape(msg.height, msg.step)[:, :row_bytes]
    if channels == 1:
        return rows
    pixels = rows.reshape(msg.height, msg.width, 3)
    return pixels[:, :, ::-1] if msg.encoding == "rgb8" else pixels  # always hand out BGR, OpenCV's order


def bundle_problem(camera_ids: Sequence[str], images: Sequence[Image],
                   sensor_camera_ids: Sequence[str]) -> tuple[str, str] | None:
    """Why a whole bundle cannot be used, as (reason, detail), or None. Such a bundle is skipped, neither estimated nor
    counted towards the reference frames (frame_from_images gives no usable image of it):
    - another number of camera ids than images: which image is whose cannot be told;
    - a camera the sensor description does not name: a bundle of another sensor (a bundle node run with another
      sensor description, a bag of another sensor). The images of the cameras that both descriptions name come from
      cameras elsewhere under another surface, and an estimate from them was published as complete (review)."""
    if len(camera_ids) != len(images):
        return ("malformed bundle", f"{len(camera_ids)} camera ids {list(camera_ids)} for {len(images)} image(s); the "
                "bundle is skipped")
    unknown = [c for c in camera_ids if c not in sensor_camera_ids]
    if unknown:
        return ("bundle of another sensor", f"cameras {unknown} are not in the sensor description, whose cameras are "
                f"{list(sensor_camera_ids)}: the bundle node (or the bag) bundles another sensor's cameras; give both "
                "the same sensor_config; the bundle is skipped")
    return None


def frame_from_images(camera_ids: Sequence[str], images: Sequence[Image], sensor_camera_ids: Sequence[str],
                      image_shape: tuple[int, int]) -> tuple[np.ndarray, np.ndarray, list[tuple[str, str]]]:
    """One bundle's image messages as a model frame, in the sensor's camera order.

    Returns the (C, H, W) uint8 frame (black where a camera gave nothing usable), camera_ok (C,) and, for each
    image that could not be used, (reason, detail): a camera's second image, an unreadable message, a wrong size. A
    bundle that cannot be used as a whole (`bundle_problem`: malformed, or of another sensor) gives no usable image
    and that one problem: skip it.
    """
    frame = np.zeros((len(sensor_camera_ids), *image_shape), np.uint8)
    camera_ok = np.zeros(len(sensor_camera_ids), bool)
    whole = bundle_problem(camera_ids, images, sensor_camera_ids)
    if whole is not None:
        return frame, camera_ok, [whole]
    problems = []
    for camera_id, msg in zip(camera_ids, images, strict=True):
        i = list(sensor_camera_ids).index(camera_id)
        if camera_ok[i]:
            problems.append((f"second image of {camera_id}", "the first one is used"))
            continue
        try:
            image = to_mono8(msg_to_array(msg, camera_id), camera_id)
        except (ImageMessageError, FrameError) as exc:
            problems.append((f"unreadable image of {camera_id}", str(exc)))
            continue
        if image.shape != image_shape:
            problems.append((f"{camera_id} image of {image.shape[1]} x {image.shape[0]} pixels",
                             f"the model needs {image_shape[1]} x {image_shape[0]}"))
            continue
        frame[i], camera_ok[i] = image, True
    return frame, camera_ok, problems
