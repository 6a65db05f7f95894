"""Each effect does what it says, only where and when the scene says, and an unnamed effect does not exist."""

import cv2
import numpy as np
import pytest

from tactile_description import load_sensor
from tactile_sim.effects import EffectContext, bind_effects, parse_effect
from tactile_sim.scene import parse_scene
from tactile_sim.simulator import Simulator, quantize

IDS = ("cam0", "cam1", "cam2", "cam3")
CTX = EffectContext(camera_ids=IDS, image_shape=(128, 128), frame_rate_hz=40.0, seed=5)


def _images(seed=0):
    """Particle-like test images: dim background with bright dots."""
    rng = np.random.default_rng(seed)
    images = np.full((4, 128, 128), 20.0, np.float32)
    for c in range(4):
        for _ in range(300):
            y, x = rng.integers(2, 126, 2)
            images[c, y - 1:y + 2, x - 1:x + 2] += rng.uniform(50, 200)
    return images


def _run(effect_nodes, frame_index=0, time_s=0.0, images=None):
    chain = bind_effects([parse_effect(n, "test") for n in effect_nodes], CTX)
    images = _images() if images is None else images
    chain.apply_images(images, frame_index, time_s)
    out = quantize(images)
    ok = np.ones(4, bool)
    chain.apply_transport(out, ok, frame_index)
    return out, ok


def test_no_effects_means_an_empty_chain():
    chain = bind_effects([], CTX)
    assert chain.image_effects == [] and chain.transport_effects == []
    clean, ok = _run([])
    np.testing.assert_array_equal(clean, quantize(_images()))
    assert ok.all()


def test_sensor_noise_has_the_requested_spread_and_changes_every_frame():
    chain = bind_effects([parse_effect({"type": "sensor_noise", "sigma": 2.0}, "t")], CTX)
    frames = []
    for i in range(3):
        images = np.full((4, 128, 128), 100.0, np.float32)
        chain.apply_images(images, i, i / 40)
        frames.append(images - 100.0)
    assert np.std(frames[0]) == pytest.approx(2.0, rel=0.05)
    assert abs(np.mean(frames[0])) < 0.05
    assert abs(np.corrcoef(frames[0].ravel(), frames[1].ravel())[0, 1]) < 0.05  # independent frame to frame


def test_defocus_blur_softens_only_the_named_camera():
    clean, _ = _run([])
    blurred, _ = _run([{"type": "defocus_blur", "sigma_px": 1.5, "cameras": ["cam1"]}])
    sharpness = [cv2.Laplacian(img.astype(np.float32), cv2.CV_32F).var() for img in blurred]
    assert sharpness[1] < 0.3 * cv2.Laplacian(clean[1].astype(np.float32), cv2.CV_32F).var()
    np.testing.assert_array_equal(blurred[[0, 2, 3]], clean[[0, 2, 3]])


def test_exposure_saturation_clips_at_255():
    clean, _ = _run([])
    bright, _ = _run([{"type": "exposure_saturation", "gain": 3.0}])
    assert bright.dtype == np.uint8 and bright.max() == 255
    assert (bright == 255).mean() > 5 * max((clean == 255).mean(), 1e-4)
    dark = clean < 60
    np.testing.assert_allclose(bright[dark], np.minimum(3.0 * _images()[dark], 255), atol=1.0)


def test_led_flicker_changes_brightness_frame_to_frame_within_its_amplitude():
    chain = bind_effects([parse_effect({"type": "led_flicker", "amplitude": 0.2}, "t")], CTX)
    gains = []
    for i in range(20):
        images = np.full((4, 8, 8), 100.0, np.float32)
        chain.apply_images(images, i, i / 40)
        gains.append(images[:, 0, 0] / 100.0)
    gains = np.array(gains)
    assert gains.min() >= 0.8 - 1e-6 and gains.max() <= 1.2 + 1e-6 and gains.std() > 0.05


def test_illumination_drift_is_slow_and_bounded():
    chain = bind_effects([parse_effect({"type": "illumination_drift", "amplitude": 0.1, "period_s": 4.0}, "t")], CTX)
    levels = []
    for i in range(160):
        images = np.full((4, 4, 4), 100.0, np.float32)
        chain.apply_images(images, i, i / 40)
        levels.append(images[:, 0, 0])
    levels = np.array(levels)
    assert levels.min() >= 90 - 1e-3 and levels.max() <= 110 + 1e-3 and levels.max() - levels.min() > 15
    # slow: the steepest change of 100 (1 + 0.1 sin(2 pi t / 4 s)) is 2 pi 10 / 4 grey levels per s, 40 frames per s
    assert np.abs(np.diff(levels, axis=0)).max() <= 2 * np.pi * 10 / 4 / 40 + 1e-3


def test_dropped_camera_is_black_and_flagged_only_in_its_frames():
    node = {"type": "camera_dropout", "cameras": ["cam2"], "frames": [3, 5], "mode": "black"}
    before, ok_before = _run([node], frame_index=2)
    during, ok_during = _run([node], frame_index=3)
    assert ok_before.all() and before[2].any()
    assert list(ok_during) == [True, True, False, True] and not during[2].any()


def test_frozen_camera_repeats_its_last_good_frame():
    chain = bind_effects([parse_effect({"type": "camera_dropout", "cameras": ["cam0"], "frames": [1, 9],
                                        "mode": "frozen"}, "t")], CTX)
    outputs = []
    for i in range(3):
        images = _images(seed=i)
        chain.apply_images(images, i, i / 40)
        out = quantize(images)
        ok = np.ones(4, bool)
        chain.apply_transport(out, ok, i)
        outputs.append((out, ok))
    np.testing.assert_array_equal(outputs[1][0][0], outputs[0][0][0])
    np.testing.assert_array_equal(outputs[2][0][0], outputs[0][0][0])
    assert not outputs[2][1][0] and outputs[2][1][1:].all()
    assert not np.array_equal(outputs[2][0][1], outputs[0][0][1])  # the other cameras go on


@pytest.mark.parametrize("order", [("black", "frozen"), ("frozen", "black")])
def test_a_frozen_camera_repeats_its_last_frame_delivered_whatever_other_dropouts_did(order):
    """cam0 black in frames [3, 6), frozen in [5, 9): frames 6-8 repeat frame 2, the last one delivered. Each dropout
    kept its own last frame: black first, they froze on black; frozen first, they repeated frame 4, which was blacked
    out and never delivered (found in review)."""
    windows = {"black": [3, 6], "frozen": [5, 9]}
    chain = bind_effects([parse_effect({"type": "camera_dropout", "cameras": ["cam0"], "frames": windows[mode],
                                        "mode": mode}, "t") for mode in order], CTX)
    outputs = []
    for i in range(10):
        out = quantize(_images(seed=i))
        ok = np.ones(4, bool)
        chain.apply_transport(out, ok, i)
        outputs.append((out[0].copy(), bool(ok[0])))
    assert [ok for _, ok in outputs] == [True] * 3 + [False] * 6 + [True]
    assert outputs[2][0].any()
    for i in range(6, 9):
        np.testing.assert_array_equal(outputs[i][0], outputs[2][0])


def test_frozen_from_the_first_frame_is_black():
    frozen, ok = _run([{"type": "camera_dropout", "cameras": ["cam3"], "mode": "frozen"}])
    assert not frozen[3].any() and not ok[3]


def test_misalignment_shifts_the_image_by_the_requested_pixels():
    clean, _ = _run([])
    moved, _ = _run([{"type": "camera_misalignment", "cameras": ["cam0"], "shift_px": [3.0, -2.0]}])
    (dx, dy), _ = cv2.phaseCorrelate(clean[0].astype(np.float64), moved[0].astype(np.float64))
    assert dx == pytest.approx(3.0, abs=0.2) and dy == pytest.approx(-2.0, abs=0.2)
    np.testing.assert_array_equal(moved[1:], clean[1:])


def test_reference_drift_dims_and_creeps_with_time():
    node = {"type": "reference_drift", "creep_px_per_s": [2.0, 0.0], "dimming_per_s": 0.1}
    start, _ = _run([node], frame_index=0, time_s=0.0)
    later, _ = _run([node], frame_index=80, time_s=2.0)
    np.testing.assert_array_equal(start, quantize(_images()))
    assert later.astype(float).mean() == pytest.approx(0.8 * start.astype(float).mean(), rel=0.03)
    (dx, _), _ = cv2.phaseCorrelate(start[0].astype(np.float64), later[0].astype(np.float64))
    assert dx == pytest.approx(4.0, abs=0.3)


def test_effects_run_in_imaging_order_whatever_the_file_order():
    """Noise is added after the exposure gain: with the gain first the noise spread is not amplified."""
    nodes = [{"type": "sensor_noise", "sigma": 1.0}, {"type": "exposure_saturation", "gain": 4.0}]
    chain = bind_effects([parse_effect(n, "t") for n in nodes], CTX)
    assert [e.spec.name for e in chain.image_effects] == ["exposure_saturation", "sensor_noise"]
    images = np.full((4, 128, 128), 10.0, np.float32)
    chain.apply_images(images, 0, 0.0)
    assert np.std(images) == pytest.approx(1.0, rel=0.1)


def test_effects_of_one_stage_keep_the_file_order():
    blur = {"type": "defocus_blur", "sigma_px": 1.0}
    shift = {"type": "camera_misalignment", "shift_px": [3.0, 0.0]}
    for nodes in ([blur, shift], [shift, blur]):
        chain = bind_effects([parse_effect(n, "t") for n in nodes], CTX)
        assert [e.spec.name for e in chain.image_effects] == [n["type"] for n in nodes]


def test_dropout_in_a_simulated_stream_flags_the_camera():
    sensor = load_sensor()
    sim = Simulator(sensor)
    scene = parse_scene({"name": "d", "seed": 2, "timeline": [{"rest": {"frames": 4}}],
                         "effects": [{"type": "camera_dropout", "cameras": ["cam1"], "frames": [2, 4]}]})
    frames = list(sim.stream(scene))
    assert [f.camera_ok[1] for f in frames] == [True, True, False, False]
    assert not frames[3].images[1].any()
    np.testing.assert_array_equal(frames[0].images, sim.reference_images())
