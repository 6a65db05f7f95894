import numpy as np
import pytest

from tactile_description import load_sensor
from tactile_description.imaging import FrameError, crop_and_downsample, to_mono8


@pytest.fixture(scope="module")
def camera():
    return load_sensor().cameras[0]


def test_output_has_the_configured_size_and_type(camera):
    frame = np.random.default_rng(0).integers(0, 256, (240, 320), dtype=np.uint8)
    image = crop_and_downsample(frame, camera)
    assert image.shape == (camera.output_size[1], camera.output_size[0])
    assert image.dtype == np.uint8


def test_crop_keeps_only_the_configured_window(camera):
    frame = np.zeros((240, 320), np.uint8)
    frame[:, : camera.crop.x] = 255  # outside the crop: must not show up
    frame[:, camera.crop.x + camera.crop.width:] = 255
    assert crop_and_downsample(frame, camera).max() == 0


def test_area_downsampling_preserves_mean_brightness(camera):
    frame = np.random.default_rng(1).integers(0, 256, (240, 320), dtype=np.uint8)
    c = camera.crop
    window = frame[c.y:c.y + c.height, c.x:c.x + c.width]
    assert abs(crop_and_downsample(frame, camera).mean() - window.mean()) < 0.5


def test_bgr_frame_is_converted_to_mono(camera):
    frame = np.full((240, 320, 3), 100, np.uint8)
    assert np.all(crop_and_downsample(frame, camera) == 100)


@pytest.mark.parametrize("frame, message", [
    (np.zeros((480, 640), np.uint8), "expects 320 x 240"),
    (np.zeros((240, 320), np.float32), "expected a uint8 image"),
    (np.zeros((240, 320, 4), np.uint8), "expected a mono or BGR image"),
    # cv2.error from the colour conversion, which a camera node does not catch (review)
    (np.zeros((0, 0, 3), np.uint8), r"the frame is empty \(shape \(0, 0, 3\)\)"),
    (np.zeros((0, 320), np.uint8), "the frame is empty"),
])
def test_bad_frames_get_a_clear_error(camera, frame, message):
    with pytest.raises(FrameError, match=message):
        crop_and_downsample(frame, camera)


def test_single_channel_frame_is_accepted():
    assert to_mono8(np.ones((4, 4, 1), np.uint8)).shape == (4, 4)
