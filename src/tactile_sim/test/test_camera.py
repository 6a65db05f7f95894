import dataclasses
import math

import cv2
import numpy as np
import pytest

from tactile_description.imaging import crop_and_downsample
from tactile_sim.camera import CameraRig


def _distorted_rig(sensor):
    """The sensor's cameras turned by different yaws and given a real distortion, to exercise every term."""
    specs = [dataclasses.replace(c, yaw_rad=0.4 * i - 0.5,
                                 lens=dataclasses.replace(c.lens, distortion=(0.05, -0.02, 0.01, -0.003)))
             for i, c in enumerate(sensor.cameras)]
    return CameraRig(specs), specs


def _gel_points(sensor, n, seed=0):
    rng = np.random.default_rng(seed)
    return rng.uniform([0, 0, -4e-3], [sensor.grid.width_m, sensor.grid.length_m, -1e-3], (n, 3))


def test_projection_matches_opencv_fisheye(sensor):
    rig, specs = _distorted_rig(sensor)
    points = _gel_points(sensor, 500)
    for i, spec in enumerate(specs):
        rotation = rig.rotation(i)
        rvec, _ = cv2.Rodrigues(rotation.T)  # world -> camera
        tvec = -rotation.T @ rig.centres_m[i]
        expected, _ = cv2.fisheye.projectPoints(points.reshape(-1, 1, 3), rvec, tvec.reshape(3, 1),
                                                spec.lens.camera_matrix, spec.lens.distortion_coefficients)
        np.testing.assert_allclose(rig.project_capture_px(i, points), expected.reshape(-1, 2), atol=1e-9)


def test_one_call_projects_pairs_of_different_cameras(sensor):
    rig, _ = _distorted_rig(sensor)
    points = _gel_points(sensor, 40)
    cams = np.arange(40) % rig.n_cameras
    together = rig.project_capture_px(cams, points)
    for i in range(rig.n_cameras):
        np.testing.assert_allclose(together[cams == i], rig.project_capture_px(i, points[cams == i]))


def test_point_on_the_axis_lands_on_the_principal_point_without_nan(sensor):
    rig = CameraRig(sensor.cameras)
    centre = rig.centres_m[0]
    points = np.array([centre + [0, 0, 5e-3], centre, centre + [1e-3, 0, 0]])  # on axis, at the centre, sideways
    proj = rig.project(0, points)
    assert np.all(np.isfinite(proj.uv_capture_px)) and np.all(np.isfinite(proj.magnification))
    lens = sensor.cameras[0].lens
    np.testing.assert_allclose(proj.uv_capture_px[0], [lens.cx, lens.cy])
    assert proj.theta_rad[2] == pytest.approx(math.pi / 2)  # 90 degrees sideways: still a finite pixel
    np.testing.assert_allclose(proj.uv_capture_px[2], [lens.cx + lens.fx * math.pi / 2, lens.cy])


def test_ray_directions_invert_the_projection(sensor):
    rig, _ = _distorted_rig(sensor)
    points = _gel_points(sensor, 300)
    for i in range(rig.n_cameras):
        rays = rig.ray_directions(i, rig.project_capture_px(i, points))
        towards = points - rig.centres_m[i]
        np.testing.assert_allclose(rays, towards / np.linalg.norm(towards, axis=1, keepdims=True), atol=1e-9)


def test_jacobian_predicts_small_motions(sensor):
    rig, _ = _distorted_rig(sensor)
    points = _gel_points(sensor, 200)
    step = np.random.default_rng(1).normal(0, 2e-6, points.shape)
    jac = rig.jacobian_output_px_per_m(2, points)
    predicted = rig.project_output_px(2, points) + np.einsum("pij,pj->pi", jac, step)
    np.testing.assert_allclose(predicted, rig.project_output_px(2, points + step), atol=1e-3)


def test_output_coordinates_follow_the_drivers_crop_and_area_downsampling(sensor):
    """A blob drawn in a capture frame lands, after crop_and_downsample, where capture_to_output_px says."""
    rig = CameraRig(sensor.cameras)
    spec = sensor.cameras[0]
    v, u = np.mgrid[0:spec.capture_size[1], 0:spec.capture_size[0]]
    for centre in [(160.0, 120.0), (101.3, 57.8), (250.6, 200.2)]:
        frame = 250 * np.exp(-((u - centre[0]) ** 2 + (v - centre[1]) ** 2) / (2 * 2.0 ** 2))
        image = crop_and_downsample(np.rint(frame).astype(np.uint8), spec).astype(np.float64)
        yy, xx = np.mgrid[0:image.shape[0], 0:image.shape[1]]
        centroid = [(xx * image).sum() / image.sum(), (yy * image).sum() / image.sum()]
        np.testing.assert_allclose(centroid, rig.capture_to_output_px(0, np.array(centre)), atol=0.05)


def test_cameras_must_share_the_image_geometry(sensor):
    other = dataclasses.replace(sensor.cameras[1], output_size=(64, 64))
    with pytest.raises(ValueError, match="must share capture size, crop and output size"):
        CameraRig([sensor.cameras[0], other])
