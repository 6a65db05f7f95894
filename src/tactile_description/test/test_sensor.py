import math
from pathlib import Path

import numpy as np
import pytest
import yaml

from tactile_description import SENSOR_ENV, SensorConfigError, default_sensor_path, load_sensor
from tactile_description.sensor import MAX_IMAGE_SIDE_PX

CONFIG = Path(__file__).resolve().parents[3] / "config"


@pytest.fixture(scope="module")
def reference():
    return load_sensor(CONFIG / "sensor.yaml")


def test_reference_sensor_matches_the_paper(reference):
    assert (reference.grid.rows, reference.grid.cols) == (26, 25)
    assert reference.grid.n_bins == 650
    assert reference.grid.bin_width_m == pytest.approx(1.96e-3)
    assert reference.grid.bin_length_m == pytest.approx(51e-3 / 26)  # 1.9615 mm: the paper rounds both to 1.96
    assert reference.camera_ids == ("cam0", "cam1", "cam2", "cam3")
    assert all(cam.output_size == (128, 128) and cam.capture_size == (320, 240) for cam in reference.cameras)


def test_units_are_converted_to_si(reference):
    base = reference.gel_layers[0]
    assert base.name == "transparent_base"
    assert base.thickness_m == pytest.approx(4e-3)
    assert reference.particles.diameter_min_m == pytest.approx(150e-6)
    assert reference.cameras[0].position_m == pytest.approx((12.25e-3, 12.75e-3, -8.5e-3))


def test_bin_centres_cover_the_surface(reference):
    centres = reference.grid.bin_centers_m()
    assert centres.shape == (26, 25, 2)
    half_bin = np.array([49e-3 / 25, 51e-3 / 26]) / 2
    assert centres[0, 0] == pytest.approx(half_bin)
    assert centres[-1, -1] == pytest.approx(np.array([49e-3, 51e-3]) - half_bin)
    assert np.all(np.diff(centres[..., 0], axis=1) > 0) and np.all(np.diff(centres[..., 1], axis=0) > 0)


def test_layer_depths_are_counted_from_the_surface(reference):
    assert reference.layer_depth_range_m("protective_top") == pytest.approx((0.0, 1e-3))
    assert reference.layer_depth_range_m("particle_layer") == pytest.approx((1e-3, 4e-3))
    assert reference.gel_thickness_m == pytest.approx(8e-3)


def test_larger_skin_loads_without_code_changes():
    skin = load_sensor(CONFIG / "skin_3x3.yaml")
    assert skin.n_cameras == 9
    assert skin.grid.n_bins == 38 * 38


def test_default_is_the_installed_description(monkeypatch):
    monkeypatch.delenv(SENSOR_ENV, raising=False)
    assert load_sensor().grid.n_bins == 650
    assert default_sensor_path().name == "sensor.yaml"


def test_environment_variable_overrides_the_default(monkeypatch):
    monkeypatch.setenv(SENSOR_ENV, str(CONFIG / "skin_3x3.yaml"))
    assert load_sensor().n_cameras == 9


def _broken(tmp_path, edit):
    raw = yaml.safe_load((CONFIG / "sensor.yaml").read_text())
    edit(raw)
    path = tmp_path / "broken.yaml"
    path.write_text(yaml.safe_dump(raw))
    return path


@pytest.mark.parametrize("edit, message", [
    (lambda r: r["surface"].pop("bin_rows"), "surface: missing key 'bin_rows'"),
    (lambda r: r["surface"].update(width_mm=-1), r"surface.width_mm must be a finite number in \[0.1, 10000\]"),
    # the camera nodes refused it as their rate_hz parameter, which the user had not set
    (lambda r: r["cameras"].update(frame_rate_hz=2000), "cameras.frame_rate_hz must be a finite number in "
                                                        r"\[1.15741e-05, 1000\], got 2000"),
    # loaded, then refused by the camera nodes as their rate_hz, which the user had not set (code review)
    (lambda r: r["cameras"].update(frame_rate_hz=1e-6), "cameras.frame_rate_hz must be a finite number in "
                                                        r"\[1.15741e-05, 1000\], got 1e-06"),
    # OverflowError rounding an infinite particle count: a traceback from every node and command (code review)
    (lambda r: r["particles"].update(per_mm3=1e300), "particles.per_mm3 = inf puts inf particles in the 7497 mm"),
    # sizes and stiffness beyond a sensor's: inf particles in inf mm^3, a modulus of inf Pa, a division by a layer
    # left no volume (review)
    (lambda r: r["surface"].update(width_mm=1e200, length_mm=1e200),
     r"surface.width_mm must be a finite number in \[0.1, 10000\], got 1e\+200"),
    (lambda r: r["gel_layers"][1].update(thickness_mm=1e308),
     r"gel_layers\[1\].thickness_mm must be a finite number in \[0.001, 1000\], got 1e\+308"),
    (lambda r: r["gel_layers"][2].update(thickness_mm=1e-300),
     r"gel_layers\[2\].thickness_mm must be a finite number in"),
    (lambda r: r["gel_layers"][1].update(youngs_modulus_kpa=1e306),
     r"gel_layers\[1\].youngs_modulus_kpa must be a finite number in \[0.001, 1e\+09\], got 1e\+306"),
    (lambda r: r["gel_layers"][0].update(name=["a", "b"]), r"gel_layers\[0\].name must be a non-empty text, got \['a'"),
    (lambda r: r["particles"].update(layer=None), r"particles.layer must be a non-empty text, got None"),
    (lambda r: r.update(frame_id="/tactile_surface"), r"frame_id must be a tf2 frame name, without a leading '/', "
                                                      r"got '/tactile_surface'"),
    (lambda r: r["cameras"]["units"][0].update(id="c" * 65), r"units\[0\]: id 'c{65}' cannot name .*up to 64"),
    # a YAML null was the frame "None" (code review)
    (lambda r: r.update(frame_id=None), r"frame_id must be a non-empty text, got None"),
    (lambda r: r.update(name=" "), r"name must be a non-empty text, got ' '"),
    (lambda r: r["surface"].update(bin_cols=2.5), "surface.bin_cols must be an integer"),
    (lambda r: r["surface"].update(bin_colls=25), r"surface: unknown key\(s\) \['bin_colls'\]"),
    # named neither the typo nor a bound it broke (walkthrough)
    (lambda r: r["surface"].update(bin_col=r["surface"].pop("bin_cols")),
     r"surface: missing key 'bin_cols' \('bin_col' is given: a typo\?\)"),
    (lambda r: r["cameras"]["units"][0].update(yaw_deg=math.inf),
     r"units\[0\].yaw_deg must be a finite number, got inf"),
    (lambda r: r["gel_layers"][1].update(poisson_ratio=0.5),
     r"gel_layers\[1\].poisson_ratio must be a finite number in"),
    (lambda r: r["gel_layers"][1].update(youngs_modulus_kpa=math.nan),
     "youngs_modulus_kpa must be a finite number in"),
    # inside the stated bounds, infinity was "in [0, inf], got inf" (review)
    (lambda r: r["surface"].update(length_mm=math.inf),
     r"surface.length_mm must be a finite number in \[0.1, 10000\], got inf"),
    (lambda r: r["particles"].update(diameter_um=[180, 150]), "diameter_um must be \\[min, max\\]"),
    (lambda r: r["particles"].update(layer="nowhere"), "no gel layer named 'nowhere'"),
    (lambda r: r["cameras"]["units"][1].update(id="cam0"), "camera ids must be unique"),
    # not a ROS name token: every camera node ended in InvalidTopicNameException (found in review)
    (lambda r: r["cameras"]["units"][1].update(id="cam-1"), r"units\[1\]: id 'cam-1' cannot name the camera's ROS "
                                                            r"topic \(/tactile/<id>/image\): use up to 64 letters, "
                                                            r"digits and"),
    (lambda r: r["cameras"]["units"][2].update(id="cam.2"), r"id 'cam.2' cannot name"),
    (lambda r: r["cameras"]["units"][0].update(id=0), r"units\[0\]: id 0 cannot name .*, e.g. cam0"),
    (lambda r: r["cameras"]["units"][3].update(id="3d"), r"id '3d' cannot name"),
    (lambda r: r["cameras"]["units"][0].update(position_mm=[10, 10, -2]), "inside the gel"),
    (lambda r: r["cameras"]["crop"].update(width=400), "does not fit"),
    (lambda r: r["cameras"].update(units=[]), "at least one camera"),
    (lambda r: r["gel_layers"][2].update(name="particle_layer"), r"gel_layers\[\*\].name must be unique"),
    (lambda r: r["particles"].update(per_mm3=1e-6), r"particles.per_mm3 = 1e-06 puts no particle in the 7497 mm\^3"),
    # failed allocations of terabytes in the simulator, with a traceback
    (lambda r: r["particles"].update(per_mm3=1e9), r"particles.per_mm3 = 1e\+09 puts 7.5e\+12 particles in the "
                                                   r"7497 mm\^3 of layer 'particle_layer', more than 1000000"),
    (lambda r: r["surface"].update(bin_rows=2600000000), "surface 2600000000 x 25 bins is more than 16384 bins"),
    (lambda r: r["cameras"]["output"].update(width=100000, height=100000),
     r"cameras.output 100000 x 100000 px is larger than the 240 x 240 px crop"),
    (lambda r: r["cameras"]["output"].update(height=241), r"cameras.output 128 x 241 px is larger than the 240 x 240"),
    (lambda r: r["cameras"].update(capture={"width": 100000, "height": 100000},
                                   crop={"x": 0, "y": 0, "width": 100000, "height": 100000}),
     f"cameras.capture 100000 x 100000 px is larger than {MAX_IMAGE_SIDE_PX} px on a side"),
])
def test_bad_descriptions_name_the_faulty_key(tmp_path, edit, message):
    with pytest.raises(SensorConfigError, match=message):
        load_sensor(_broken(tmp_path, edit))


def test_missing_and_corrupt_files_get_clear_errors(tmp_path):
    with pytest.raises(SensorConfigError, match="cannot read sensor description"):
        load_sensor(tmp_path / "absent.yaml")
    corrupt = tmp_path / "corrupt.yaml"
    corrupt.write_text("surface: [unclosed")
    with pytest.raises(SensorConfigError, match="not valid YAML"):
        load_sensor(corrupt)


def test_a_file_that_is_not_utf8_text_is_refused_naming_it(tmp_path, monkeypatch):
    binary = tmp_path / "binary.yaml"
    binary.write_bytes(bytes(range(128, 256)) + bytes(72))  # 200 bytes, the first not valid UTF-8
    with pytest.raises(SensorConfigError, match=f"sensor description {binary} is not UTF-8 text"):
        load_sensor(binary)
    monkeypatch.setenv(SENSOR_ENV, str(binary))
    with pytest.raises(SensorConfigError, match="is not UTF-8 text"):
        load_sensor()


def test_the_largest_capture_and_an_output_as_large_as_the_crop_are_accepted(tmp_path):
    size = {"width": MAX_IMAGE_SIDE_PX, "height": MAX_IMAGE_SIDE_PX}
    sensor = load_sensor(_broken(tmp_path, lambda r: r["cameras"].update(
        capture=size, crop={"x": 0, "y": 0, **size}, output=size)))
    assert sensor.cameras[0].output_size == (MAX_IMAGE_SIDE_PX, MAX_IMAGE_SIDE_PX)


def test_exponent_floats_read_as_numbers(tmp_path):
    """YAML 1.1 (PyYAML) reads 1e-3 or 5e-1 as strings; the stack's files read them as numbers, as YAML 1.2 does."""
    text = (CONFIG / "sensor.yaml").read_text()
    text = text.replace("frame_rate_hz: 40.0", "frame_rate_hz: 4e1").replace("per_mm3: 1.0", "per_mm3: 1e0")
    path = tmp_path / "exponents.yaml"
    path.write_text(text)
    sensor = load_sensor(path)
    assert sensor.frame_rate_hz == 40.0 and sensor.particle_count == 7497


def test_the_particle_count_is_the_density_times_the_layer_volume_rounded(reference):
    assert reference.particle_layer_volume_m3 == pytest.approx(49e-3 * 51e-3 * 3e-3)
    assert reference.particle_count == 7497   # 1 per mm^3 in 49 x 51 x 3 mm
