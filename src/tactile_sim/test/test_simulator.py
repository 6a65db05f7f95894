import re
import tracemalloc

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from tactile_description import load_sensor
from tactile_sim import Simulator, load_scene, write_dataset
from tactile_sim.contact import Contact, Sphere
from tactile_sim.effects import SceneError
from tactile_sim.scene import parse_scene, scenes_directory


@pytest.fixture(scope="module")
def sim():
    return Simulator(load_sensor())


def test_stream_yields_every_frame_with_the_documented_arrays(sim):
    scene = load_scene("multi_contact")
    frames = list(sim.stream(scene, frames=5))
    assert [f.index for f in frames] == list(range(5))
    rows, cols = sim.sensor.grid.rows, sim.sensor.grid.cols
    for f in frames:
        assert f.images.shape == (4, 128, 128) and f.images.dtype == np.uint8
        assert f.bin_forces_n.shape == (rows, cols, 3) and f.bin_forces_n.dtype == np.float32
        assert np.all(np.isfinite(f.bin_forces_n)) and f.bin_forces_n[..., 2].sum() > 0.1
        assert f.camera_ok.dtype == bool and f.camera_ok.all()
        assert 2 <= len(f.contacts) <= 4
    assert frames[1].time_s == pytest.approx(1 / sim.sensor.frame_rate_hz)


OVERLAPPING = {"name": "overlap", "seed": 1, "timeline": [{"contacts": {"contacts": [
    {"x_mm": 20, "y_mm": 20, "depth_mm": 1.0}, {"x_mm": 23, "y_mm": 20, "depth_mm": 1.0}]}}]}


def test_contacts_that_may_overlap_are_refused_where_the_ground_truth_would_count_them_twice(sim, tmp_path):
    """The analytic model computes each contact alone and adds their forces: two 10 mm spheres 1 mm deep 3 mm apart
    (contact radii 2.24 mm each) would carry about twice the force of their shared area. The numerical model solves
    them together and takes the scene."""
    scene = parse_scene(OVERLAPPING, "overlap.yaml")
    scene.validate(sim.sensor)  # the sensor can play it: whether it may overlap depends on the model
    with pytest.raises(SceneError, match=re.escape(
            "overlap.yaml.timeline[0].contacts.contacts[0] and contacts[1] overlap: 3 mm apart, closer than their "
            "contact radii together (4.47 mm): the analytic ground-truth model computes each contact alone and adds "
            "their forces, counting the overlap twice; move them apart, or label the scene with the numerical model "
            "(tactile-sim generate or render --model numerical; the simulated camera node and training "
            "from a scene have the analytic one only)")):
        sim.stream(scene)
    with pytest.raises(SceneError, match="counting the overlap twice"):  # before any file is written
        write_dataset(sim, scene, tmp_path / "data", progress=False)
    assert not (tmp_path / "data").exists()
    random = parse_scene({"name": "r", "seed": 1, "timeline": [{"random_presses": {
        "frames": 2, "contacts_per_frame": [1, 2], "depth_mm": [0.5, 1.5], "min_separation_mm": 5}}]}, "r.yaml")
    with pytest.raises(SceneError, match=re.escape(
            "r.yaml.timeline[0].random_presses.min_separation_mm (5 mm) lets two contacts overlap: at the deepest "
            "press their contact radii add up to 5.48 mm")):
        sim.stream(random)
    # A flat punch at depth 0 presses nothing, although a punch's contact radius is its own at any depth.
    untouched = parse_scene({**OVERLAPPING, "timeline": [{"contacts": {"contacts": [
        {"x_mm": 20, "y_mm": 20, "depth_mm": 1.0},
        {"x_mm": 23, "y_mm": 20, "depth_mm": 0.0, "indenter": {"shape": "flat_punch", "diameter_mm": 6}}]}}]})
    assert next(sim.stream(untouched)).bin_forces_n[..., 2].sum() > 0.1
    numerical = Simulator(sim.sensor, ground_truth="numerical")
    apart = parse_scene({**OVERLAPPING, "timeline": [{"contacts": {"contacts": [
        {"x_mm": 20, "y_mm": 20, "depth_mm": 1.0}, {"x_mm": 24.5, "y_mm": 20, "depth_mm": 1.0}]}}]})
    together, alone = next(numerical.stream(scene)), sim.bin_forces([Contact(0.02, 0.02, 1e-3, Sphere(0.005))])
    # Solved together, two overlapping presses carry less than twice one alone.
    assert alone[..., 2].sum() < together.bin_forces_n[..., 2].sum() < 1.9 * alone[..., 2].sum()
    assert next(sim.stream(apart)).bin_forces_n[..., 2].sum() == pytest.approx(2 * alone[..., 2].sum(), rel=1e-3)


def test_no_contact_gives_the_reference_frames(sim):
    scene = parse_scene({"name": "rest", "seed": 1, "timeline": [{"rest": {"frames": 2}}]})
    for f in sim.stream(scene):
        np.testing.assert_array_equal(f.images, sim.reference_images())
        assert not f.bin_forces_n.any()


def test_reference_images_are_a_copy(sim):
    ref = sim.reference_images()
    ref[:] = 0
    assert sim.reference_images().any()


def test_deeper_presses_change_the_images_more(sim):
    change = []
    for depth in (0.3e-3, 0.8e-3, 1.5e-3):
        forces = sim.bin_forces([Contact(0.02, 0.03, depth, Sphere(0.005))])
        change.append(np.abs(sim.render(forces) - sim.renderer.reference).sum())
    assert change[0] < change[1] < change[2]


def test_streams_are_reproducible(sim):
    scene = load_scene("effects")
    a = [f.images for f in sim.stream(scene, frames=3)]
    b = [f.images for f in sim.stream(scene, frames=3)]
    for x, y in zip(a, b, strict=True):
        np.testing.assert_array_equal(x, y)


def test_streaming_memory_does_not_grow_with_the_number_of_frames(sim):
    """Memory held by a running stream after 20 and after 120 frames is the same: nothing accumulates per frame."""
    tracemalloc.start()
    try:
        held = {}
        for frame in sim.stream(load_scene("paper_grid"), frames=121):
            index = frame.index
            del frame
            if index in (20, 120):
                held[index] = tracemalloc.get_traced_memory()[0]
    finally:
        tracemalloc.stop()
    assert held[120] - held[20] < 64 * 1024


def test_the_nine_camera_skin_renders_and_streams():
    skin = load_sensor(scenes_directory().parent / "skin_3x3.yaml")
    sim9 = Simulator(skin)
    assert sim9.reference_images().shape == (9, 128, 128)
    frames = list(sim9.stream(load_scene("multi_contact"), frames=2))
    assert frames[0].images.shape == (9, 128, 128) and frames[0].camera_ok.shape == (9,)
    assert frames[0].bin_forces_n.shape == (38, 38, 3)
    changed = [np.abs(frames[0].images[c].astype(int) - sim9.reference_images()[c]).sum() for c in range(9)]
    assert max(changed) > 1000


def test_a_camera_that_sees_no_particle_is_refused_naming_it():
    """A lens typo (cx 1600 for 160) or a camera far beside the surface gave blank images, and a data set and a model
    trained on them, without a word (walkthrough)."""
    import dataclasses

    from tactile_description import SensorConfigError

    sensor = load_sensor()
    far = dataclasses.replace(sensor.cameras[2], position_m=(0.3, 0.01, sensor.cameras[2].position_m[2]))
    beside = dataclasses.replace(sensor, cameras=(*sensor.cameras[:2], far, sensor.cameras[3]))
    with pytest.raises(SensorConfigError, match=r"camera\(s\) cam2 \(1.\d\) see no particle of the gel: .*check their "
                                                r"position_mm and yaw_deg, and the lens"):
        Simulator(beside)
    lens = dataclasses.replace(sensor.cameras[0].lens, cx=1600.0)
    off_centre = dataclasses.replace(sensor, cameras=tuple(dataclasses.replace(c, lens=lens) for c in sensor.cameras))
    with pytest.raises(SensorConfigError, match=r"camera\(s\) cam0 \(0\), cam1 \(0\), cam2 \(0\), cam3 \(0\) see no"):
        Simulator(off_centre)


def test_unknown_ground_truth_model_is_refused():
    with pytest.raises(ValueError, match="unknown ground-truth model"):
        Simulator(load_sensor(), ground_truth="magic")


@settings(max_examples=25, deadline=None)
@given(x_mm=st.floats(-6.0, 55.0), y_mm=st.floats(-6.0, 57.0), depth_mm=st.floats(0.0, 1.5),
       shear_x_mm=st.floats(-1.0, 1.0), shear_y_mm=st.floats(-1.0, 1.0), count=st.integers(1, 3))
def test_any_allowed_press_gives_finite_forces_and_valid_images(sim, x_mm, y_mm, depth_mm, shear_x_mm, shear_y_mm,
                                                               count):
    contacts = [Contact((x_mm + 15 * i) * 1e-3, y_mm * 1e-3, depth_mm * 1e-3, Sphere(0.005),
                        (shear_x_mm * 1e-3, shear_y_mm * 1e-3)) for i in range(count)]
    forces = sim.bin_forces(contacts)
    assert np.all(np.isfinite(forces))
    images = sim.render(forces)
    assert np.all(np.isfinite(images))
    scene = parse_scene({"name": "h", "seed": 1, "timeline": [{"contacts": {"contacts": [
        {"x_mm": c.x_m * 1e3, "y_mm": c.y_m * 1e3, "depth_mm": c.depth_m * 1e3,
         "shear_mm": [v * 1e3 for v in c.shear_m]} for c in contacts]}}],
        "effects": [{"type": "sensor_noise", "sigma": 3.0}, {"type": "exposure_saturation", "gain": 3.0}]})
    try:
        scene.validate(sim.sensor)
    except SceneError as exc:  # a contact the scene refuses as touching nothing must indeed press nothing
        refused = re.search(r"contacts\[(\d+)\]: a press at .* it would press nothing", str(exc))
        assert refused, exc
        assert np.abs(sim.bin_forces([contacts[int(refused.group(1))]])).max() < 1e-9  # newtons: none to speak of
        return
    frame = next(sim.stream(scene))
    assert frame.images.dtype == np.uint8 and frame.images.max() == 255  # saturated, clipped, not wrapped
