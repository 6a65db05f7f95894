"""The renderer: the fast path (model images drawn directly, moved particles only) against the slow exact path
(every particle drawn at capture resolution, then crop_and_downsample as for a real camera)."""

import numpy as np
import pytest

from tactile_description import load_sensor
from tactile_description.imaging import crop_and_downsample
from tactile_sim.contact import Contact, Sphere
from tactile_sim.render import Optics, ParticleRenderer, Spots
from tactile_sim.scene import parse_scene
from tactile_sim.simulator import Simulator, quantize

#: Documented agreement of the fast path with capture rendering + crop_and_downsample (uint8 images): the mean
#: absolute difference stays below half a grey level; single pixels differ by up to ~10 grey levels where a bright
#: particle's spot meets the area filter at an unlucky sub-pixel phase (a Gaussian spot stands in for the filtered
#: one); the change a press makes (difference to the rest frame) agrees to within 20 % of its energy.
MEAN_ABS_GREY = 0.6
P999_ABS_GREY = 12.0
DIFFERENCE_ENERGY_ERROR = 0.2


@pytest.fixture(scope="module")
def sim():
    return Simulator(load_sensor())


@pytest.fixture(scope="module")
def capture_renderer(sim):
    return ParticleRenderer(sim.sensor, sim.particles, "capture")


def _through_the_driver(capture_images, sensor):
    frames = quantize(capture_images.copy())
    return np.stack([crop_and_downsample(frames[i], cam) for i, cam in enumerate(sensor.cameras)]).astype(np.float64)


def test_rest_frames_match_capture_rendering_through_the_driver(sim, capture_renderer):
    fast = sim.reference_images().astype(np.float64)
    slow = _through_the_driver(capture_renderer.reference, sim.sensor)
    error = np.abs(fast - slow)
    assert error.mean() < MEAN_ABS_GREY
    assert np.percentile(error, 99.9) <= P999_ABS_GREY


@pytest.mark.parametrize("x_mm, y_mm, depth_mm", [(20.0, 30.0, 1.5), (12.25, 12.75, 0.6), (45.0, 5.0, 1.0)])
def test_pressed_frames_match_capture_rendering_through_the_driver(sim, capture_renderer, x_mm, y_mm, depth_mm):
    forces = sim.bin_forces([Contact(x_mm * 1e-3, y_mm * 1e-3, depth_mm * 1e-3, Sphere(0.005))])
    fast = quantize(sim.render(forces)).astype(np.float64)
    slow = _through_the_driver(capture_renderer.render(sim.particle_positions_m(forces)), sim.sensor)
    error = np.abs(fast - slow)
    assert error.mean() < MEAN_ABS_GREY
    assert np.percentile(error, 99.9) <= P999_ABS_GREY
    change_fast = fast - sim.reference_images()
    change_slow = slow - _through_the_driver(capture_renderer.reference, sim.sensor)
    assert np.sum((change_fast - change_slow) ** 2) < DIFFERENCE_ENERGY_ERROR * np.sum(change_slow ** 2)


@pytest.mark.parametrize("x_mm, y_mm", [(30.0, 20.0), (12.25, 12.75)])  # between cameras, right above one
def test_redrawing_only_moved_particles_matches_drawing_all(sim, x_mm, y_mm):
    """The fast path skips particles that cannot change a pixel by `redraw_grey_levels` and moves spots mostly
    to first order; against drawing every particle exactly, it stays within a few grey levels."""
    forces = sim.bin_forces([Contact(x_mm * 1e-3, y_mm * 1e-3, 1.5e-3, Sphere(0.005))])
    shortcut = sim.render(forces)
    full = sim.renderer.render(sim.particle_positions_m(forces))
    assert np.abs(shortcut - full).max() < 2.5
    assert np.abs(shortcut - full).mean() < 0.01


def test_a_press_changes_the_image_near_the_contact_only(sim):
    """The camera under the press sees a change around the contact's image point and nothing far from it."""
    x, y = sim.sensor.cameras[0].position_m[:2]
    forces = sim.bin_forces([Contact(x, y, 1.0e-3, Sphere(0.005))])
    change = np.abs(sim.render(forces)[0] - sim.renderer.reference[0])
    centre = sim.renderer.rig.project_output_px(0, np.array([[x, y, -1e-3]]))[0]
    rows, cols = np.mgrid[0:change.shape[0], 0:change.shape[1]]
    distance = np.hypot(cols - centre[0], rows - centre[1])
    assert change[distance < 20].max() > 50        # particles under the indenter visibly move
    assert change[distance > 45].max() < 1.0       # far away nothing changes


def test_a_moved_particle_appears_moved(sim):
    """One particle displaced alone: its spot's centroid moves by the projection of the displacement."""
    renderer = sim.renderer
    cam = 0
    uv = renderer.rest_spots.uv_px[:len(sim.particles)]
    peak = renderer.rest_spots.peak[:len(sim.particles)]
    inside = (uv[:, 0] > 20) & (uv[:, 0] < 108) & (uv[:, 1] > 20) & (uv[:, 1] < 108)
    particle = int(np.flatnonzero(inside)[np.argmax(peak[inside])])
    displacement = np.zeros((len(sim.particles), 3))
    displacement[particle] = [0.3e-3, -0.2e-3, 0.0]
    change = renderer.render_displaced(displacement)[cam] - renderer.reference[cam]
    moved_to = sim.particles.positions_m[particle] + displacement[particle]
    new_uv = renderer.rig.project_output_px(cam, moved_to[None])[0]
    rows, cols = np.mgrid[0:change.shape[0], 0:change.shape[1]]
    gain = np.clip(change, 0, None) * (np.hypot(cols - new_uv[0], rows - new_uv[1]) < 3)
    loss = np.clip(-change, 0, None) * (np.hypot(cols - uv[particle, 0], rows - uv[particle, 1]) < 3)
    np.testing.assert_allclose([(cols * gain).sum() / gain.sum(), (rows * gain).sum() / gain.sum()], new_uv, atol=0.15)
    np.testing.assert_allclose([(cols * loss).sum() / loss.sum(), (rows * loss).sum() / loss.sum()], uv[particle],
                               atol=0.15)
    assert np.hypot(*(new_uv - uv[particle])) > 2.0


def test_particles_pressed_towards_a_camera_look_bigger(sim):
    renderer = sim.renderer
    cams = np.zeros(2, dtype=int)
    point = np.array([[*sim.sensor.cameras[0].position_m[:2], -2e-3]])
    spots = renderer.spots(cams, np.vstack([point, point - [0, 0, 0.5e-3]]), np.zeros(2, dtype=int))
    assert spots.sigma_px[1] > spots.sigma_px[0] and spots.peak[1] > spots.peak[0]


def test_spots_far_outside_the_image_are_dropped_not_wrapped(sim):
    renderer = sim.renderer
    spots = Spots(camera_index=np.array([0, 1]), uv_px=np.array([[-50.0, 10.0], [10.0, 500.0]]),
                  sigma_px=np.array([0.6, 0.6]), peak=np.array([200.0, 200.0]))
    assert np.all(renderer.draw(spots) == 0)


def test_images_are_finite_for_extreme_displacements(sim):
    displacement = np.zeros((len(sim.particles), 3))
    camera = np.array(sim.sensor.cameras[0].position_m)
    displacement[0] = camera - sim.particles.positions_m[0]                   # exactly onto a camera's lens
    displacement[1:50, 2] = camera[2] - sim.particles.positions_m[1:50, 2]    # onto the camera plane
    displacement[50:100] = [0.05, 0.05, 0.0]                                  # thrown far outside the view
    image = sim.renderer.render_displaced(displacement)
    assert np.all(np.isfinite(image))


def test_moved_spots_match_exact_projection_for_the_deepest_press(sim):
    """moved_spots moves spots to first order (exactly for large motions): far below a pixel off at 1.5 mm."""
    renderer = sim.renderer
    n = len(sim.particles)
    for x_mm, y_mm in [(20.0, 30.0), (12.25, 12.75), (24.5, 25.5)]:  # between cameras, above one, in the centre
        forces = sim.bin_forces([Contact(x_mm * 1e-3, y_mm * 1e-3, 1.5e-3, Sphere(0.005))])
        displacement = sim.gel.displacements_m(forces).astype(np.float64)
        moved = np.flatnonzero(np.abs(displacement).sum(axis=1) > 0)
        rest = (np.arange(renderer.n_cameras)[:, None] * n + moved).ravel()
        cams, particle = rest // n, rest % n
        linear = renderer.moved_spots(rest, displacement[particle])
        exact = renderer.spots(cams, sim.particles.positions_m[particle] + displacement[particle], particle)
        assert np.hypot(*(linear.uv_px - exact.uv_px).T).max() < 0.05
        np.testing.assert_allclose(linear.peak, exact.peak, rtol=0.05, atol=0.5)
        np.testing.assert_allclose(linear.sigma_px, exact.sigma_px, rtol=0.02)


def test_bad_renderer_settings_are_refused(sim):
    with pytest.raises(ValueError, match="resolution must be one of"):
        ParticleRenderer(sim.sensor, sim.particles, "preview")
    with pytest.raises(ValueError, match="psf_sigma_capture_px must be > 0"):
        ParticleRenderer(sim.sensor, sim.particles, "output", Optics(psf_sigma_capture_px=0.0))


def test_spots_just_outside_each_cameras_image_draw_their_visible_part_only(sim):
    """A spot whose centre is within the window radius outside the image (below the last camera's included) draws
    exactly the Gaussian's taps that fall on that camera's pixels, and nothing on any other camera."""
    renderer = sim.renderer
    r, height, width = renderer.window_radius, renderer.height, renderer.width
    rows, cols = np.mgrid[0:height, 0:width]
    places = [(-r, -r), (width + r - 1, height + r - 1), (0.5 * width, height), (-r + 0.3, height + r - 1.2),
              (width + r - 1, -r)]
    for cam in range(renderer.n_cameras):
        for u, v in places:
            spots = Spots(camera_index=np.array([cam]), uv_px=np.array([[u, v]]), sigma_px=np.array([0.9]),
                          peak=np.array([100.0]))
            image = renderer.draw(spots)
            cu, cv = np.rint(u), np.rint(v)
            window = (np.abs(cols - cu) <= r) & (np.abs(rows - cv) <= r)
            expected = np.where(window, 100.0 * np.exp(-((cols - u) ** 2 + (rows - v) ** 2) / (2 * 0.9**2)), 0.0)
            np.testing.assert_allclose(image[cam], expected, rtol=1e-5, atol=1e-6)
            assert image[cam].max() > 0.0 and not np.delete(image, cam, axis=0).any()


def test_a_preview_that_cannot_be_saved_leaves_no_figure_open(sim, tmp_path):
    """pyplot keeps every open figure: a preview that failed to save stayed in memory (code review)."""
    import matplotlib.pyplot as plt

    from tactile_sim.preview import save_preview

    frame = next(sim.stream(parse_scene({"name": "p", "seed": 1, "timeline": [{"rest": {"frames": 1}}]})))
    plt.close("all")
    with pytest.raises(OSError):
        save_preview(tmp_path / "no such directory" / "p.png", frame, sim.reference_images(), sim.sensor)
    assert plt.get_fignums() == []
