"""The cameras under the gel: poses, OpenCV fisheye projection and the capture -> model-image pixel mapping.

The projection is OpenCV's fisheye model (documentation of cv2.fisheye.projectPoints), written out in numpy so
it vectorises over thousands of (camera, particle) pairs and also handles rays at or beyond 90 degrees without
a division by zero. For a point (X, Y, Z) in the camera frame:

    rho = sqrt(X^2 + Y^2),  theta = atan2(rho, Z)           (OpenCV: theta = atan(rho / Z), the same for Z > 0)
    theta_d = theta (1 + k1 theta^2 + k2 theta^4 + k3 theta^6 + k4 theta^8)
    x' = theta_d X / rho,  y' = theta_d Y / rho             (-> X / Z and Y / Z as rho -> 0)
    u = fx x' + cx,        v = fy y' + cy                    (capture pixels; pixel centres at integers)

Camera frame: every camera looks along +z of the sensor frame; yaw turns it about z, so its x axis is
(cos yaw, sin yaw, 0) and its y axis (-sin yaw, cos yaw, 0) in the sensor frame (right-handed, z forward).

All methods take `camera_index`, either one index for all points or one per point (shape (P,)), so a single
call covers every camera of the rig.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from tactile_description import CameraSpec

#: Step of the central differences in `CameraRig.jacobian_output_px_per_m`: 1 um, far below any particle's
#: distance from a camera and far above float64 rounding at millimetre scale.
_JACOBIAN_STEP_M = 1e-6


@dataclass(frozen=True)
class Projection:
    """Where points land in the capture image, with the ray angles the appearance model needs."""

    uv_capture_px: np.ndarray   # (P, 2)
    theta_rad: np.ndarray       # (P,) angle from the optical axis
    distance_m: np.ndarray      # (P,) from the optical centre
    magnification: np.ndarray   # (P,) local image scale relative to the axis: sqrt(radial * tangential)


class CameraRig:
    """All cameras of one sensor description, their parameters stacked for vectorised projection."""

    def __init__(self, cameras: Sequence[CameraSpec]):
        if not cameras:
            raise ValueError("CameraRig needs at least one camera; the sensor description lists none")
        self.specs = tuple(cameras)
        self.camera_ids = tuple(c.camera_id for c in cameras)
        self.n_cameras = len(cameras)
        yaw = np.array([c.yaw_rad for c in cameras])
        self._cos, self._sin = np.cos(yaw), np.sin(yaw)
        self.centres_m = np.array([c.position_m for c in cameras], dtype=np.float64)
        self._k = np.array([c.lens.distortion for c in cameras], dtype=np.float64)
        self._f = np.array([[c.lens.fx, c.lens.fy] for c in cameras])
        self._c = np.array([[c.lens.cx, c.lens.cy] for c in cameras])
        self._one_lens = len({c.lens for c in cameras}) == 1
        #: Pixels of a mean focal length: the size of one radian near the optical axis.
        self.focal_px = self._f.mean(axis=1)
        sizes = {(c.capture_size, c.output_size, (c.crop.x, c.crop.y, c.crop.width, c.crop.height)) for c in cameras}
        if len(sizes) != 1:
            raise ValueError("all cameras of a sensor must share capture size, crop and output size; the "
                             f"description mixes {sorted(sizes)}")
        spec = cameras[0]
        self.capture_size = spec.capture_size   # (width, height)
        self.output_size = spec.output_size     # (width, height)
        crop = spec.crop
        self.crop = crop
        # INTER_AREA maps output pixel j onto the capture span [j s, (j + 1) s) of the crop, whose centre is
        # (j + 0.5) s - 0.5 in capture pixel-centre coordinates: hence the half-pixel terms in capture_to_output_px.
        self.output_per_capture_px = np.array([spec.output_size[0] / crop.width, spec.output_size[1] / crop.height])
        self._crop_origin = np.array([crop.x, crop.y], dtype=np.float64)

    def rotation(self, camera_index: int) -> np.ndarray:
        """3x3 matrix whose columns are the camera's axes in the sensor frame (p_sensor = R p_camera + centre)."""
        c, s = self._cos[camera_index], self._sin[camera_index]
        return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])

    def to_camera_frame(self, camera_index, points_m: np.ndarray) -> np.ndarray:
        """(P, 3) sensor-frame points -> (P, 3) camera-frame points."""
        d = np.asarray(points_m, dtype=np.float64) - self.centres_m[camera_index]
        c, s = self._cos[camera_index], self._sin[camera_index]
        return np.stack([c * d[:, 0] + s * d[:, 1], c * d[:, 1] - s * d[:, 0], d[:, 2]], axis=1)

    def _lens(self, camera_index):
        """(k1..k4 as a (4, P) or (4,) array, f, c) of the cameras; constants when all cameras share one lens."""
        if self._one_lens:
            return self._k[0], self._f[0], self._c[0]
        return self._k[camera_index].reshape(-1, 4).T, self._f[camera_index], self._c[camera_index]

    def _fisheye(self, camera_index, p: np.ndarray):
        """rho, theta, theta_d and the pixel coordinates of camera-frame points `p` (P, 3)."""
        k, f, c = self._lens(camera_index)
        rho = np.hypot(p[:, 0], p[:, 1])
        theta = np.arctan2(rho, p[:, 2])
        t2 = theta * theta
        theta_d = theta * (1.0 + t2 * (k[0] + t2 * (k[1] + t2 * (k[2] + t2 * k[3]))))
        # theta_d / rho -> 1 / Z on the axis: guard the 0 / 0 at rho = 0.
        on_axis = rho < 1e-12
        scale = np.where(on_axis, 1.0 / np.where(p[:, 2] == 0.0, 1.0, p[:, 2]), theta_d / np.where(on_axis, 1.0, rho))
        return rho, theta, theta_d, p[:, :2] * scale[:, None] * f + c

    def project(self, camera_index, points_m: np.ndarray) -> Projection:
        """The fisheye projection of (P, 3) sensor-frame points (see the module docstring)."""
        p = self.to_camera_frame(camera_index, points_m)
        rho, theta, theta_d, uv = self._fisheye(camera_index, p)
        k, _, _ = self._lens(camera_index)
        t2 = theta * theta
        radial = 1.0 + t2 * (3 * k[0] + t2 * (5 * k[1] + t2 * (7 * k[2] + t2 * 9 * k[3])))  # d theta_d / d theta
        # theta_d / sin(theta) -> 1 on the axis.
        on_axis = rho < 1e-12
        tangential = np.where(on_axis, 1.0, theta_d / np.where(on_axis, 1.0, np.sin(theta)))
        return Projection(uv_capture_px=uv, theta_rad=theta, distance_m=np.hypot(rho, p[:, 2]),
                          magnification=np.sqrt(np.abs(radial * tangential)))

    def project_capture_px(self, camera_index, points_m: np.ndarray) -> np.ndarray:
        """(P, 3) sensor-frame points -> (P, 2) capture pixel coordinates (u right, v down)."""
        return self._fisheye(camera_index, self.to_camera_frame(camera_index, points_m))[3]

    def capture_to_output_px(self, camera_index, uv_capture: np.ndarray) -> np.ndarray:
        """Capture pixel coordinates -> model-image (cropped, downsampled) pixel coordinates."""
        del camera_index  # every camera shares the crop (checked in __init__); kept for a uniform signature
        return (uv_capture - self._crop_origin + 0.5) * self.output_per_capture_px - 0.5

    def project_output_px(self, camera_index, points_m: np.ndarray) -> np.ndarray:
        """(P, 3) sensor-frame points -> (P, 2) model-image pixel coordinates."""
        return self.capture_to_output_px(camera_index, self.project_capture_px(camera_index, points_m))

    def jacobian_output_px_per_m(self, camera_index, points_m: np.ndarray) -> np.ndarray:
        """(P, 2, 3): d(model-image u, v) / d(sensor-frame x, y, z), by central differences of the projection."""
        points_m = np.asarray(points_m, dtype=np.float64)
        jacobian = np.empty((len(points_m), 2, 3))
        for axis in range(3):
            step = np.zeros(3)
            step[axis] = _JACOBIAN_STEP_M
            forward = self.project_output_px(camera_index, points_m + step)
            backward = self.project_output_px(camera_index, points_m - step)
            jacobian[:, :, axis] = (forward - backward) / (2 * _JACOBIAN_STEP_M)
        return jacobian

    def ray_directions(self, camera_index: int, uv_capture: np.ndarray) -> np.ndarray:
        """(P, 2) capture pixel coordinates -> (P, 3) unit ray directions in the sensor frame (inverse projection).

        theta comes from theta_d by Newton's method on theta_d(theta) - r = 0 (exact at once for an
        undistorted lens, k1..k4 = 0; a few steps for realistic coefficients).
        """
        xy = (np.asarray(uv_capture, dtype=np.float64) - self._c[camera_index]) / self._f[camera_index]
        r = np.hypot(xy[:, 0], xy[:, 1])
        k1, k2, k3, k4 = self._k[camera_index]
        theta = r.copy()
        for _ in range(20):
            t2 = theta * theta
            value = theta * (1.0 + t2 * (k1 + t2 * (k2 + t2 * (k3 + t2 * k4)))) - r
            slope = 1.0 + t2 * (3 * k1 + t2 * (5 * k2 + t2 * (7 * k3 + t2 * 9 * k4)))
            theta = theta - value / np.maximum(slope, 1e-6)
        safe_r = np.where(r > 0.0, r, 1.0)
        sin_theta = np.sin(theta)
        rays = np.stack([xy[:, 0] / safe_r * sin_theta, xy[:, 1] / safe_r * sin_theta, np.cos(theta)], axis=1)
        return rays @ self.rotation(camera_index).T
