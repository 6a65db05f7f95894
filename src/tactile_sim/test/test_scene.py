import dataclasses
import math

import numpy as np
import pytest
import yaml

from tactile_description import SENSOR_ENV, SensorConfigError, load_sensor
from tactile_sim.contact import FlatPunch, Sphere, ground_truth_model, max_depth_m
from tactile_sim.effects import SceneError
from tactile_sim.scene import load_scene, parse_scene, scenes_directory

SHIPPED = ["paper_grid", "paper_grid_shear", "edge_corner", "multi_contact", "shear", "effects", "demo"]


@pytest.fixture(scope="module")
def skin():
    return load_sensor(scenes_directory().parent / "skin_3x3.yaml")


def _all_contacts(scene, sensor):
    return list(scene.contacts(sensor))


@pytest.mark.parametrize("name", SHIPPED)
def test_shipped_scenes_load_for_both_sensors_and_respect_the_depth_limit(name, sensor, skin):
    scene = load_scene(name, sensor)
    load_scene(name, skin)
    frames = _all_contacts(scene, sensor)
    assert len(frames) == len(scene) > 0
    for contacts in frames:
        for c in contacts:
            assert 0.0 <= c.depth_m <= max_depth_m(sensor, c.shape)
            assert math.isfinite(c.x_m) and math.isfinite(c.y_m)


@pytest.mark.parametrize("name", [n for n in SHIPPED if n != "effects"])  # effects names cameras cam1-cam3
def test_shipped_scenes_fit_a_surface_of_half_the_width(name, sensor):
    """Places in fractions of the surface (demo, shear, multi_contact) and scenes that follow it (press_grid,
    random_presses) fit a 24.5 mm strip; the demo's path in millimetres ran beside it. multi_contact's random presses,
    four 12 mm apart, find no room there: refused before any frame, not as the frames are made."""
    strip = dataclasses.replace(sensor, grid=dataclasses.replace(sensor.grid, width_m=24.5e-3))
    scene = load_scene(name, strip)
    if name == "multi_contact":
        with pytest.raises(SceneError, match=r"timeline\[2\].random_presses: frame \d+ of the segment found room for "
                                             r"only 3 of 4 contacts 12 mm apart"):
            scene.check_playable(strip, ground_truth_model(strip))
        # Its fixed layouts fit, and so do its first random frames: a limit is checked as it is played, and no frame
        # past it is drawn (contacts() made one more, which could fail where the limit ends in such a segment).
        scene = scene.limited(4)
        scene.check_playable(strip, ground_truth_model(strip))
        assert len(_all_contacts(scene, strip)) == 4
    else:
        scene.check_playable(strip, ground_truth_model(strip))
    beside = 3e-3 if name == "edge_corner" else 0.0  # its presses reach up to 3 mm beyond the edges, on purpose
    assert all(-beside <= c.x_m <= 24.5e-3 + beside
               for contacts in _all_contacts(scene.limited(2000), strip) for c in contacts)


def test_places_in_fractions_of_the_surface_follow_its_size(sensor):
    """Where millimetres stay where they are."""
    scene = parse_scene(_scene(timeline=[
        {"press": {"x_fraction": 0.5, "y_fraction": 0.25, "depths_mm": [1.0]}},
        {"contacts": {"contacts": [{"x_fraction": 0.25, "y_fraction": 0.5, "depth_mm": 1.0},
                                   {"x_mm": 10, "y_mm": 40, "depth_mm": 1.0}]}},
        {"path": {"frames": 3, "depth_mm": 1.0, "waypoints_fraction": [[0.2, 0.2], [0.8, 0.8]]}}]), "test.yaml")
    strip = dataclasses.replace(sensor, grid=dataclasses.replace(sensor.grid, width_m=24.5e-3))
    for surface, width in ((sensor, 49e-3), (strip, 24.5e-3)):
        press, contacts, start, _, end = _all_contacts(scene, surface)
        assert (press[0].x_m, press[0].y_m) == pytest.approx((0.5 * width, 0.25 * 51e-3))
        assert contacts[0].x_m == pytest.approx(0.25 * width) and contacts[1].x_m == pytest.approx(10e-3)
        assert (start[0].x_m, end[0].x_m) == pytest.approx((0.2 * width, 0.8 * width))


@pytest.mark.parametrize("segment, message", [
    ({"press": {"x_fraction": 0.5, "y_mm": 20, "depths_mm": [1.0]}},
     r"timeline\[0\].press: give x_mm and y_mm, or x_fraction and y_fraction, not a mix of the two"),
    ({"press": {"depths_mm": [1.0]}},
     r"timeline\[0\].press: missing its place: x_mm and y_mm, or x_fraction and y_fraction"),
    ({"path": {"frames": 3, "depth_mm": 1.0}}, r"timeline\[0\].path: missing its waypoints: waypoints_mm or "
                                              r"waypoints_fraction"),
    ({"path": {"frames": 3, "waypoints_mm": [[1, 1], [2, 2]], "waypoints_fraction": [[0, 0], [1, 1]]}},
     r"timeline\[0\].path: give waypoints_mm or waypoints_fraction, not both"),
    ({"path": {"frames": 3, "waypoints_fraction": [[0.5, 0.5]]}},
     r"timeline\[0\].path.waypoints_fraction must list at least two \[x, y\] points \(finite numbers, fractions\)"),
    ({"path": {"frames": 3, "depth_mm": 1.0, "waypoints_fraction": [[0.5, 0.5], [1.2, 0.5]]}},
     r"timeline\[0\].path.waypoints_fraction\[1\]: a press at \(58.8, 25.5\) mm is 9.8 mm off .* it would press "
     r"nothing \(fractions of the surface's width and length beyond 0 to 1 lie beside it\)"),
])
def test_places_in_fractions_are_checked_as_those_in_millimetres(sensor, segment, message):
    with pytest.raises(SceneError, match=message):
        parse_scene(_scene(timeline=[segment]), "test.yaml").validate(sensor)


def test_paper_grid_is_a_seeded_grid_of_vertical_sphere_presses_up_to_1_5_mm(sensor):
    scene = load_scene("paper_grid", sensor)
    frames = _all_contacts(scene, sensor)
    assert 45000 <= len(frames) <= 47000
    presses = [c for contacts in frames for c in contacts]
    assert all(len(contacts) <= 1 for contacts in frames)
    assert all(c.shape == Sphere(0.005) and c.shear_m == (0.0, 0.0) for c in presses)
    depths = np.array([c.depth_m for c in presses])
    assert depths.max() <= 1.5e-3 and depths.max() > 1.4e-3 and depths.min() < 0.2e-3
    xy = np.array([(c.x_m, c.y_m) for c in presses])
    assert xy[:, 0].min() < 4e-3 and xy[:, 0].max() > sensor.grid.width_m - 4e-3   # covers the whole surface
    assert xy[:, 1].min() < 4e-3 and xy[:, 1].max() > sensor.grid.length_m - 4e-3
    again = _all_contacts(load_scene("paper_grid", sensor), sensor)
    assert again == frames                                                            # seeded: reproducible
    assert [e.name for e in scene.effects] == ["sensor_noise"]


def test_paper_grid_shear_presses_like_paper_grid_then_shears_each_press_up_to_1_mm_in_any_direction(sensor):
    def placed(frames):
        return [[(c.x_m, c.y_m, c.depth_m) for c in contacts] for contacts in frames]

    sheared = _all_contacts(load_scene("paper_grid_shear", sensor), sensor)
    assert placed(sheared) == placed(_all_contacts(load_scene("paper_grid", sensor), sensor))
    shear = np.array([c.shear_m for contacts in sheared for c in contacts])
    magnitude = np.hypot(shear[:, 0], shear[:, 1])
    assert magnitude.max() <= 1e-3 and magnitude.max() > 0.99e-3 and magnitude.min() < 0.01e-3
    assert abs(np.median(magnitude) - 0.5e-3) < 0.02e-3                    # uniform over 0-1 mm
    quadrants = np.histogram(np.arctan2(shear[:, 1], shear[:, 0]), bins=4, range=(-np.pi, np.pi))[0]
    assert quadrants.min() > 0.23 * len(shear)                              # every direction alike


def test_hard_case_scenes_are_what_their_names_say(sensor):
    edge = [c for f in _all_contacts(load_scene("edge_corner"), sensor) for c in f]
    off = [c for c in edge if not (0 <= c.x_m <= sensor.grid.width_m and 0 <= c.y_m <= sensor.grid.length_m)]
    assert len(off) > 10                                             # some centres lie off the surface
    multi = _all_contacts(load_scene("multi_contact"), sensor)
    assert {len(f) for f in multi} == {2, 3, 4}
    shear = [c for f in _all_contacts(load_scene("shear"), sensor) for c in f]
    assert np.mean([math.hypot(*c.shear_m) >= 0.1e-3 for c in shear]) > 0.9
    names = {e.name for e in load_scene("effects").effects}
    assert names >= {"sensor_noise", "defocus_blur", "led_flicker", "illumination_drift", "exposure_saturation",
                     "camera_dropout", "camera_misalignment", "reference_drift"}


def test_a_limited_scene_is_a_prefix_of_the_full_one(sensor):
    scene = load_scene("multi_contact")
    assert len(scene.limited(7)) == 7
    assert _all_contacts(scene.limited(7), sensor) == _all_contacts(scene, sensor)[:7]


def test_demo_path_ramps_in_and_out(sensor):
    frames = _all_contacts(load_scene("demo"), sensor)
    depths = [f[0].depth_m if f else 0.0 for f in frames]
    assert depths[0] == 0.0 and depths[-1] == 0.0 and max(depths) == pytest.approx(1e-3)


def _scene(**overrides):
    raw = {"name": "t", "seed": 1, "timeline": [{"rest": {"frames": 2}}]}
    raw.update(overrides)
    return raw


@pytest.mark.parametrize("raw, message", [
    (_scene(effects=[{"type": "lens_flare"}]), "unknown effect type 'lens_flare'"),
    (_scene(effects=[{"type": []}]), r"unknown effect type \[\]"),  # a TypeError before
    (_scene(effects=[{"type": "sensor_noise", "sigmaa": 1}]), "has no key 'sigmaa'"),
    (_scene(effects=[{"type": "sensor_noise", "sigma": -1}]), r"'sigma' must be a finite number in \(0, 255\]"),
    (_scene(effects=[{"type": "camera_dropout"}]), "needs 'cameras'"),
    (_scene(effects=[{"type": "camera_dropout", "cameras": ["cam0"], "frames": [5, 2]}]), "first < stop"),
    (_scene(effects=[{"type": "camera_dropout", "cameras": ["cam0"], "mode": "grey"}]), "'black' or 'frozen'"),
    (_scene(timeline=[{"press": {"x_mm": 1, "y_mm": 2}}]), "missing key 'depths_mm'"),
    (_scene(timeline=[{"jump": {"frames": 1}}]), "unknown segment kind 'jump'"),
    (_scene(timeline=[{"rest": {"frames": 1, "colour": "red"}}]), r"unknown key\(s\) \['colour'\]"),
    (_scene(timeline=[]), "timeline must be a non-empty list"),
    (_scene(indenter={"shape": "cube"}), "must be 'sphere' or 'flat_punch'"),
    (_scene(seed="x"), "seed must be an integer"),
    ({"seed": 1, "timeline": [{"rest": {"frames": 1}}]}, "missing key 'name'"),
    (_scene(timeline=[{"random_presses": {"frames": 3, "depth_mm": [1.0, 0.5]}}]), "min <= max"),
    (_scene(timeline=[{"press_grid": {"cols": 1, "rows": 1, "depth_mm": [0.1, 0.2], "depths_per_position": 1,
                                      "shear_mm": [1.0, 0.5]}}]), "shear_mm.*min <= max"),
    (_scene(indenter={"shape": "sphere", "diameter_mm": 400}),
     r"indenter.diameter_mm must be a finite number in \[0.1, 100"),
    (yaml.safe_load("{name: t, seed: 1, timeline: [{path: {frames: 4, depth_mm: 1, waypoints_mm: [[0, .nan], [9, 9]]}}"
                    "]}"),
     r"timeline\[0\].path.waypoints_mm must list at least two \[x, y\] points \(finite numbers"),
    (_scene(timeline=[{"path": {"frames": 4, "depth_mm": 1, "waypoints_mm": [[True, 1], [9, 9]]}}]), "waypoints_mm"),
    (_scene(timeline=[{"random_presses": {"frames": 3, "depth_mm": 1, "contacts_per_frame": [True, True]}}]),
     "contacts_per_frame must be an integer"),
    (_scene(name="a/b"), "name must be a file name"),
    (_scene(name="../x"), "name must be a file name"),
    (_scene(timeline=[{"rest": {"frames": 6_000_000}}, {"rest": {"frames": 6_000_000}}]),
     r"timeline\[1\].rest: the scene reaches 12000000 frames here, more than 10000000"),
    (_scene(effects=[{"type": "sensor_noise", "sigma": 1e300}]), r"'sigma' must be a finite number in \(0, 255\]"),
    # Found in review: an OverflowError binding the effect (a half-written data set), sin(inf) = NaN in the images,
    # an OverflowError in the check that the contacts fit, no side force at a friction of 1e20
    (_scene(effects=[{"type": "reference_drift", "frames": [10**400, 10**400 + 1]}]),
     r"'frames' must be \[first, stop\) frame indices with 0 <= first < stop <= 10000000"),
    (_scene(effects=[{"type": "illumination_drift", "period_s": 1e-310}]),
     r"'period_s' must be a finite number >= 0.001"),
    (_scene(timeline=[{"random_presses": {"frames": 3, "depth_mm": 1, "min_separation_mm": 1e199}}]),
     r"min_separation_mm must be a finite number in \[0, 1000\]"),
    (_scene(timeline=[{"random_presses": {"frames": 3, "depth_mm": 1, "region": "edges",
                                          "edge_band_mm": [-1e200, 0]}}]), r"edge_band_mm .* within \+-1000 mm"),
    (_scene(timeline=[{"press": {"x_mm": 1, "y_mm": 2, "depths_mm": [1], "friction": 1e20}}]),
     r"friction must be a finite number in \[0, 10\]"),
    # the other coordinate is no typo: "missing key 'x_fraction' ('y_fraction' is given: a typo?)" (review)
    (_scene(timeline=[{"press": {"x_fraction": 0.5, "depths_mm": [1]}}]), "press: give both x_fraction and y_fraction"),
    (_scene(timeline=[{"press": {"y_fraction": 0.5, "depths_mm": [1]}}]), "press: give both x_fraction and y_fraction"),
    (_scene(timeline=[{"press": {"x_mm": 5, "depths_mm": [1]}}]), r"press: give both x_mm and y_mm"),
    # a key like a missing one may be a typo of it
    (_scene(timeline=[{"press_grid": {"cols": 2, "rows": 2, "deptth_mm": [0.1, 1.0], "depths_per_position": 1}}]),
     r"missing key 'depth_mm' \('deptth_mm' is given: a typo\?\)"),
    # one bound: "in [0, inf], got inf" (review)
    (_scene(timeline=[{"press_grid": {"cols": 2, "rows": 2, "depth_mm": [0.1, 1.0], "depths_per_position": 1,
                                      "margin_mm": float("inf")}}]),
     r"margin_mm must be a finite number >= 0, got inf"),
    # Accepted and without effect before (review): a key of the other region, an effect after the scene's last frame,
    # a description that is not text; and the count refused is the one given, not [17, 17]
    (_scene(timeline=[{"random_presses": {"frames": 3, "depth_mm": 1, "region": "edges", "margin_mm": 30}}]),
     r"random_presses.margin_mm does not apply to region 'edges'.*remove margin_mm"),
    (_scene(timeline=[{"random_presses": {"frames": 3, "depth_mm": 1, "edge_band_mm": [0, 1]}}]),
     r"random_presses.edge_band_mm does not apply to region 'surface'.*remove edge_band_mm"),
    (_scene(effects=[{"type": "sensor_noise", "sigma": 1, "frames": [2, 10]}]),
     r"effects\[0\]: effect 'sensor_noise' starts at frame 2, but the scene has 2 frames \(0 to 1\): it would never "
     r"act"),
    (_scene(description=[1, 2]), r"description must be text, got \[1, 2\]"),
    (_scene(timeline=[{"random_presses": {"frames": 3, "depth_mm": 1, "contacts_per_frame": 17}}]),
     r"<= max <= 16, got 17$"),
])
def test_bad_scenes_get_clear_errors(raw, message):
    with pytest.raises(SceneError, match=message):
        parse_scene(raw, "test.yaml")


def test_depth_beyond_the_sensors_limit_is_refused(sensor):
    limit_mm = max_depth_m(sensor, Sphere(0.005)) * 1e3
    scene = parse_scene(_scene(timeline=[{"press": {"x_mm": 20, "y_mm": 20, "depths_mm": [limit_mm + 0.1]}}]))
    with pytest.raises(SceneError, match="deeper than the deepest allowed press"):
        scene.validate(sensor)


def _press(**body):
    return _scene(timeline=[{"press": dict({"x_mm": 20, "y_mm": 20, "depths_mm": [1.0]}, **body)}])


def _grid(**body):
    return _scene(timeline=[{"press_grid": dict({"cols": 2, "rows": 2, "depth_mm": [0.1, 1.0],
                                                 "depths_per_position": 1}, **body)}])


def _random(**body):
    return _scene(timeline=[{"random_presses": dict({"frames": 3, "depth_mm": [0.1, 1.0]}, **body)}])


@pytest.mark.parametrize("raw, message", [
    (_press(indenter={"shape": "sphere", "diameter_mm": 40}, depths_mm=[2.0]),
     r"test.yaml.timeline\[0\].press: a press 2 mm deep is deeper than the deepest allowed press of 0.512 mm .*"
     r"chi = sqrt\(R d\) / h at most 0.8"),
    (_press(indenter={"shape": "flat_punch", "diameter_mm": 20}),
     r"timeline\[0\].press: a flat punch 20 mm in diameter .* a / h = 2.5, above 1, .* at most 8 mm in diameter"),
    (_scene(timeline=[{"contacts": {"contacts": [
        {"x_mm": 10, "y_mm": 10, "depth_mm": 1.5},
        {"x_mm": 30, "y_mm": 30, "depth_mm": 1.2, "indenter": {"shape": "sphere", "diameter_mm": 2}}]}}]),
     r"timeline\[0\].contacts.contacts\[1\]: a press 1.2 mm deep .* allowed press of 1 mm .*the sphere's radius"),
    (_random(margin_mm=30), r"random_presses.margin_mm \(30 mm\) leaves no room on the 49 x 51 mm surface"),
    (_grid(margin_mm=40), r"press_grid.margin_mm \(40 mm\) leaves no room"),
    (_random(contacts_per_frame=[3, 3], min_separation_mm=100),
     r"random_presses.min_separation_mm \(100 mm\): 3 contacts that far apart cannot fit in the 49 x 51 mm"),
    (_grid(jitter_mm=1000), r"press_grid.jitter_mm \(1000 mm\) would move presses off the surface: .* 12.25 mm"),
    (_press(shear_mm=[3.0, 4.0]), r"timeline\[0\].press.shear_mm: a shear of 5 mm is longer than the 4 mm"),
    (_random(shear_mm=[0.0, 10.0]), r"random_presses.shear_mm: a shear of 10 mm"),
    # a 10 mm sphere 1 mm deep touches within sqrt(5 x 1) = 2.24 mm of its centre: 3 mm off the surface, nothing
    (_press(x_mm=-3, y_mm=20), r"timeline\[0\].press: a press at \(-3, 20\) mm is 3 mm off the 49 x 51 mm surface, "
                               r"beyond the 2.24 mm its contact reaches at its deepest: it would press nothing"),
    (_scene(timeline=[{"contacts": {"contacts": [{"x_mm": 10, "y_mm": 10, "depth_mm": 1.0},
                                                 {"x_mm": 60, "y_mm": 60, "depth_mm": 1.0}]}}]),
     r"timeline\[0\].contacts.contacts\[1\]: a press at \(60, 60\) mm is 14.2 mm off"),
    # a path's waypoints too: the demo scene's path ran beside a 24.5 mm strip, pressing nothing most of the time
    (_scene(timeline=[{"path": {"frames": 10, "depth_mm": 1.0, "waypoints_mm": [[10, 10], [60, 10], [10, 10]]}}]),
     r"timeline\[0\].path.waypoints_mm\[1\]: a press at \(60, 10\) mm is 11 mm off the 49 x 51 mm surface"),
    # random presses at an edge whose whole band lies beyond the contact's reach: every frame pressed nothing (review)
    (_random(region="edges", edge_band_mm=[-10, -8]),
     r"random_presses.edge_band_mm \(-10 to -8 mm\) lies wholly beside the surface, farther out than the 2.24 mm .*"
     r"its upper end must be above -2.24 mm"),
])
def test_presses_outside_the_models_or_off_the_surface_are_refused_before_any_frame(sensor, raw, message):
    scene = parse_scene(raw, "test.yaml")
    with pytest.raises(SceneError, match=message):
        scene.validate(sensor)
    with pytest.raises(SceneError, match=message):
        next(scene.contacts(sensor))


def test_a_press_off_the_edge_that_still_touches_the_surface_is_taken(sensor):
    """2 mm off, within the 2.24 mm a 10 mm sphere 1 mm deep reaches: part of its contact is on the surface."""
    scene = parse_scene(_press(x_mm=-2, y_mm=20), "test.yaml")
    scene.validate(sensor)
    assert next(scene.contacts(sensor))[0].x_m == pytest.approx(-0.002)


def test_each_contact_is_checked_against_its_own_indenter(sensor):
    """A deep press of the default sphere beside a shallow one of a small sphere is fine."""
    scene = parse_scene(_scene(timeline=[{"contacts": {"contacts": [
        {"x_mm": 10, "y_mm": 10, "depth_mm": 1.5},
        {"x_mm": 30, "y_mm": 30, "depth_mm": 0.3, "indenter": {"shape": "sphere", "diameter_mm": 2}}]}}]))
    scene.validate(sensor)
    assert [c.shape for c in _all_contacts(scene, sensor)[0]] == [Sphere(0.005), Sphere(0.001)]


def test_a_limit_before_random_presses_without_room_plays_the_frames_before_them(sensor):
    scene = parse_scene(_scene(timeline=[{"rest": {"frames": 3}}, {"random_presses": {
        "frames": 4, "contacts_per_frame": 4, "min_separation_mm": 45.0, "depth_mm": [0.3, 0.5]}}]), "test.yaml")
    with pytest.raises(SceneError, match=r"timeline\[1\].random_presses: frame 0 of the segment found room for only"):
        scene.check_playable(sensor, ground_truth_model(sensor))
    scene.limited(3).check_playable(sensor, ground_truth_model(sensor))
    assert _all_contacts(scene.limited(3), sensor) == [(), (), ()]


def test_random_presses_that_find_no_room_for_every_contact_are_refused_not_shortened(sensor):
    """16 centres 15 mm apart would fit on a grid, but not when drawn at random one by one."""
    scene = parse_scene(_random(frames=1, contacts_per_frame=16, min_separation_mm=15), "test.yaml")
    scene.validate(sensor)
    with pytest.raises(SceneError, match=r"random_presses: frame 0 of the segment found room for only \d+ of 16"):
        _all_contacts(scene, sensor)


def test_a_limit_never_lengthens_a_scene():
    scene = load_scene("multi_contact")
    assert len(scene.limited(5).limited(100)) == 5 and len(scene.limited(100).limited(5)) == 5


def test_effect_naming_a_camera_the_sensor_lacks_is_refused(sensor):
    scene = parse_scene(_scene(effects=[{"type": "defocus_blur", "cameras": ["cam7"]}]))
    with pytest.raises(SceneError, match=r"names cameras \['cam7'\]"):
        scene.validate(sensor)


def test_flat_punch_contacts_and_explicit_frames(sensor):
    scene = parse_scene(_scene(timeline=[{"contacts": {"repeat": 3, "contacts": [
        {"x_mm": 10, "y_mm": 10, "depth_mm": 0.5, "indenter": {"shape": "flat_punch", "diameter_mm": 4}},
        {"x_mm": 30, "y_mm": 30, "depth_mm": 1.0, "shear_mm": [0.2, 0.0]}]}}]))
    frames = _all_contacts(scene, sensor)
    assert len(frames) == 3 and frames[0][0].shape == FlatPunch(0.002) and frames[0][1].shear_m == (0.0002, 0.0)


def test_installed_scenes_resolve_by_name_with_or_without_the_extension():
    assert load_scene("demo.yaml").name == load_scene("demo").name == "demo"


def test_a_directory_of_a_scenes_name_in_the_working_directory_does_not_hide_the_installed_scene(tmp_path,
                                                                                                 monkeypatch):
    """`--scene demo` run where a folder `demo` lies (a data set written there, say) reads the installed scene."""
    monkeypatch.chdir(tmp_path)
    (tmp_path / "demo").mkdir()
    assert load_scene("demo").name == "demo"
    (tmp_path / "demo.yaml").write_text(yaml.safe_dump({**_scene(), "name": "mine"}))  # a file of the name given is
    assert load_scene("demo.yaml").name == "mine"


def test_a_scene_given_as_a_path_is_that_file_never_an_installed_scene(tmp_path, monkeypatch):
    """`--scene ./demo.yaml` names a file here: missing, it is an error, not the installed demo without a word
    (Path("./demo.yaml") is Path("demo.yaml"), a plain name; found in review)."""
    monkeypatch.chdir(tmp_path)
    for given in ("./demo.yaml", "./demo", f"{tmp_path}/demo.yaml"):
        with pytest.raises(SceneError, match="cannot read scene file"):
            load_scene(given)
    (tmp_path / "demo.yaml").write_text(yaml.safe_dump({**_scene(), "name": "mine"}))
    assert load_scene("./demo.yaml").name == "mine"


def test_random_presses_at_an_edge_that_reach_the_surface_with_part_of_their_band_are_taken(sensor):
    """A band reaching beyond the contact radius is the edge_corner scene's design: its presses farthest out touch
    nothing (frames at rest among the hard cases), the others part of the surface."""
    scene = parse_scene(_random(region="edges", edge_band_mm=[-10, -2]))
    scene.validate(sensor)  # -2 mm is within the 2.24 mm a 10 mm sphere 1 mm deep reaches
    assert len(_all_contacts(scene, sensor)) == 3


def test_unknown_scene_names_list_the_installed_ones(tmp_path):
    with pytest.raises(SceneError, match="installed scenes are .*paper_grid"):
        load_scene("no_such_scene")
    bad = tmp_path / "bad.yaml"
    bad.write_text("name: [unclosed")
    with pytest.raises(SceneError, match="not valid YAML"):
        load_scene(bad)
    good = tmp_path / "good.yaml"
    good.write_text(yaml.safe_dump(_scene()))
    assert len(load_scene(good)) == 2


def test_a_scene_file_that_is_not_utf8_text_is_refused_naming_it(tmp_path):
    binary = tmp_path / "binary.yaml"
    binary.write_bytes(bytes(range(128, 256)) + bytes(72))  # 200 bytes, the first not valid UTF-8
    with pytest.raises(SceneError, match=f"scene file {binary} is not UTF-8 text"):
        load_scene(binary)


def test_exponent_floats_in_a_scene_file_are_numbers(tmp_path, sensor):
    """YAML 1.1 (PyYAML) reads 5e-1 as a string; a scene file reads it as a number, as YAML 1.2 does."""
    path = tmp_path / "exponents.yaml"
    path.write_text("{name: t, seed: 1, timeline: [{press: {x_mm: 2.45e1, y_mm: 25, depths_mm: [5e-1, 1e0]}}]}")
    frames = _all_contacts(load_scene(path, sensor), sensor)
    assert [c.depth_m for (c,) in frames] == pytest.approx([0.5e-3, 1e-3])
    assert frames[0][0].x_m == pytest.approx(24.5e-3)


def test_installed_scenes_are_found_by_name_with_the_sensor_description_elsewhere(monkeypatch, tmp_path):
    """$TACTILE_SENSOR_CONFIG pointing at a user's own sensor file made every scene name unknown: the scenes were
    looked up next to it ("installed scenes are []", found in review)."""
    own = tmp_path / "my_sensor.yaml"
    own.write_text((scenes_directory().parent / "skin_3x3.yaml").read_text())
    monkeypatch.setenv(SENSOR_ENV, str(own))
    assert scenes_directory() != tmp_path / "scenes"
    assert load_scene("demo", load_sensor()).name == "demo"


def test_without_tactile_bringup_installed_a_scene_name_is_a_scene_error_saying_so(monkeypatch, tmp_path):
    """With $TACTILE_SENSOR_CONFIG set, the error said no description was given and to set that variable, and it was
    a SensorConfigError, which the nodes and eval's hard cases do not take for a scene's (found in review)."""
    own = tmp_path / "my_sensor.yaml"
    own.write_text((scenes_directory().parent / "sensor.yaml").read_text())
    monkeypatch.setenv(SENSOR_ENV, str(own))
    monkeypatch.setenv("AMENT_PREFIX_PATH", str(tmp_path))
    with pytest.raises(SceneError, match="no scene file 'demo', and tactile_bringup, which installs the default sensor "
                                         "description and the scenes, is not installed: source scripts/env.sh"):
        load_scene("demo")
    monkeypatch.delenv(SENSOR_ENV)
    with pytest.raises(SensorConfigError, match=f"no sensor description given, and tactile_bringup, .*; or set "
                                                f"{SENSOR_ENV}"):
        load_sensor()
