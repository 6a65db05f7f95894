import dataclasses
import json
from pathlib import Path

import pytest

from tactile_description import load_sensor
from tactile_description.made_for import NAMED_CHANGES, changed_fields, changes_text, made_for_problem, physical_fields

CONFIG = Path(__file__).resolve().parents[3] / "config"


@pytest.fixture(scope="module")
def reference():
    return load_sensor(CONFIG / "sensor.yaml")


def test_physical_fields_are_json_values_of_what_shapes_the_images(reference):
    fields = physical_fields(reference)
    assert set(fields) == {"grid", "gel_layers", "particles", "cameras"}
    assert json.loads(json.dumps(fields)) == fields  # JSON as written into model.json: tuples as lists
    assert fields["cameras"][0]["position_m"] == pytest.approx([12.25e-3, 12.75e-3, -8.5e-3])
    assert fields["gel_layers"][1]["youngs_modulus_pa"] == pytest.approx(137.7e3)


def test_a_renamed_sensor_at_another_frame_rate_has_changed_nothing_a_model_sees(reference):
    renamed = dataclasses.replace(reference, name="my_sensor", frame_id="my_frame", frame_rate_hz=30.0,
                                  source="elsewhere.yaml")
    assert changed_fields(physical_fields(reference), physical_fields(renamed)) == []


def test_changes_name_cameras_by_id_and_gel_layers_by_name(reference):
    cameras = list(reference.cameras)
    cameras[1] = dataclasses.replace(cameras[1], position_m=(0.0, 0.0, -8.5e-3), yaw_rad=0.5)
    layers = list(reference.gel_layers)
    layers[2] = dataclasses.replace(layers[2], youngs_modulus_pa=300e3)
    edited = dataclasses.replace(reference, cameras=tuple(cameras), gel_layers=tuple(layers),
                                 particles=dataclasses.replace(reference.particles, seed=7))
    assert changed_fields(physical_fields(reference), physical_fields(edited)) == [
        "gel_layers[protective_top].youngs_modulus_pa", "particles.seed", "cameras[cam1].position_m",
        "cameras[cam1].yaw_rad"]


def test_a_camera_renamed_or_left_out_is_named_as_such(reference):
    fields = physical_fields(reference)
    fewer = dataclasses.replace(reference, cameras=reference.cameras[:3])
    assert changed_fields(fields, physical_fields(fewer)) == ["cameras"]
    renamed = dataclasses.replace(reference, cameras=(dataclasses.replace(reference.cameras[0], camera_id="left"),
                                                      *reference.cameras[1:]))
    assert changed_fields(fields, physical_fields(renamed)) == ["cameras[0].camera_id"]


def test_a_field_that_only_one_side_has_is_not_compared(reference):
    """A field that a later version adds (with its default) leaves the models trained before it as they were."""
    fields = physical_fields(reference)
    newer = json.loads(json.dumps(fields))
    newer["cameras"][0]["exposure_s"] = 0.01
    newer["illumination"] = {"lux": 300}
    assert changed_fields(fields, newer) == changed_fields(newer, fields) == []
    newer["grid"]["rows"] = 27
    assert changed_fields(fields, newer) == ["grid.rows"]


def test_changes_text_names_the_first_few_and_counts_the_rest():
    assert changes_text(["grid.rows"]) == "grid.rows"
    many = [f"cameras[cam{i}].yaw_rad" for i in range(NAMED_CHANGES + 3)]
    text = changes_text(many)
    assert text.endswith(" and 3 more") and text.count("yaw_rad") == NAMED_CHANGES


def test_cameras_are_matched_by_id_in_any_order_and_a_vector_is_one_field(reference):
    fields = physical_fields(reference)
    reordered = dataclasses.replace(reference, cameras=reference.cameras[::-1])
    assert changed_fields(fields, physical_fields(reordered)) == []
    moved = list(reordered.cameras)
    moved[0] = dataclasses.replace(moved[0], position_m=(0.0, 0.0, -8.5e-3))  # cam3, listed first
    assert changed_fields(fields, physical_fields(dataclasses.replace(reordered, cameras=tuple(moved)))) == [
        "cameras[cam3].position_m"]


def test_numbers_equal_to_a_billionth_are_the_same_value():
    """12.75 mm converted to metres as 12.75 * 1e-3 or 12.75 / 1000 differs in the last bit: not a change."""
    assert 12.75 * 1e-3 != 12.75 / 1000
    assert changed_fields({"grid": {"width_m": 12.75 * 1e-3}}, {"grid": {"width_m": 12.75 / 1000}}) == []
    assert changed_fields({"grid": {"width_m": 0.049}}, {"grid": {"width_m": 0.049 * (1 + 1e-6)}}) == ["grid.width_m"]


def test_a_record_read_back_is_checked_before_it_is_compared(reference):
    assert made_for_problem(physical_fields(reference)) == ""
    assert made_for_problem({"grid": {}, "gel_layers": [], "particles": {}}) == "lacks ['cameras']"
    assert made_for_problem([]).startswith("must be a mapping of ")
