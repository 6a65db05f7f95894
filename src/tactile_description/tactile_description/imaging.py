"""From a camera's capture frame (320 x 240 for the reference sensor) to the model's input (128 x 128 mono8).

The crop and output size come from the sensor description, so the simulator and a real camera produce the
same image for the same scene. Downsampling uses area averaging (cv2.INTER_AREA), which is what a 240 -> 128
reduction needs to avoid aliasing the particle pattern.
"""

from __future__ import annotations

import cv2
import numpy as np

from tactile_description import CameraSpec


class FrameError(ValueError):
    """A capture frame that cannot be turned into a model image (wrong size, type or channels)."""


def to_mono8(frame: np.ndarray, camera_id: str = "camera") -> np.ndarray:
    """A uint8 (H, W) image from a uint8 mono (H, W), (H, W, 1) or BGR (H, W, 3) frame."""
    if not isinstance(frame, np.ndarray) or frame.dtype != np.uint8:
        raise FrameError(f"{camera_id}: expected a uint8 image, got "
                         f"{getattr(frame, 'dtype', type(frame).__name__)}")
    if frame.size == 0:  # OpenCV's colour conversion raised cv2.error, which a camera node does not catch (review)
        raise FrameError(f"{camera_id}: the frame is empty (shape {frame.shape})")
    if frame.ndim == 3 and frame.shape[2] == 1:
        return frame[:, :, 0]
    if frame.ndim == 3 and frame.shape[2] == 3:
        return cv2.cvtColor(frame, cv2.COLOR_BGR2GRAY)
    if frame.ndim == 2:
        return frame
    raise FrameError(f"{camera_id}: expected a mono or BGR image, got shape {frame.shape}")


def crop_and_downsample(frame: np.ndarray, camera: CameraSpec) -> np.ndarray:
    """The model image of `camera` from its capture frame: mono8, cropped, area-downsampled to the output size."""
    mono = to_mono8(frame, camera.camera_id)
    width, height = camera.capture_size
    if mono.shape != (height, width):
        raise FrameError(f"{camera.camera_id}: capture frame is {mono.shape[1]} x {mono.shape[0]}, the sensor "
                         f"description expects {width} x {height}")
    c = camera.crop
    cropped = mono[c.y:c.y + c.height, c.x:c.x + c.width]
    return cv2.resize(cropped, camera.output_size, interpolation=cv2.INTER_AREA)
