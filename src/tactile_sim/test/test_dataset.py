import json

import numpy as np
import pytest

from tactile_description import load_sensor
from tactile_sim import DatasetError, Simulator, load_scene, open_dataset, write_dataset
from tactile_sim.scene import scenes_directory


@pytest.fixture(scope="module")
def sim():
    return Simulator(load_sensor())


@pytest.fixture(scope="module")
def written(sim, tmp_path_factory):
    out = tmp_path_factory.mktemp("ds") / "effects"
    write_dataset(sim, load_scene("effects"), out, progress=False, frames=12)
    return out


def test_written_data_set_reads_back_as_streamed(sim, written):
    ds = open_dataset(written, sim.sensor)
    frames = list(sim.stream(load_scene("effects"), frames=12))
    assert len(ds) == 12 and ds.images.shape == (12, 4, 128, 128)
    for f in frames:
        np.testing.assert_array_equal(ds.images[f.index], f.images)
        np.testing.assert_array_equal(ds.forces[f.index], f.bin_forces_n)
        np.testing.assert_array_equal(ds.camera_ok[f.index], f.camera_ok)
    np.testing.assert_array_equal(ds.reference, sim.reference_images())
    assert isinstance(ds.images, np.memmap)
    meta = ds.meta
    assert meta["camera_ids"] == ["cam0", "cam1", "cam2", "cam3"] and meta["rows"] == 26 and meta["cols"] == 25
    assert meta["scene"] == "effects" and meta["frame_count"] == 12 and meta["complete"]
    assert len(ds.contacts()) == 12 and ds.contacts()[0][0]["shape"] == "Sphere"


def test_non_empty_output_is_not_overwritten_by_accident(sim, written):
    with pytest.raises(DatasetError, match="not empty"):
        write_dataset(sim, load_scene("effects"), written, progress=False, frames=2)


def _copy_of(written, directory):
    directory.mkdir()
    for f in written.iterdir():
        (directory / f.name).write_bytes(f.read_bytes())
    return directory


def test_truncated_array_is_reported(sim, written, tmp_path):
    broken = _copy_of(written, tmp_path / "broken")
    data = (broken / "images.npy").read_bytes()
    (broken / "images.npy").write_bytes(data[: len(data) // 2])
    with pytest.raises(DatasetError, match="images.npy is corrupt or truncated"):
        open_dataset(broken)


def test_incomplete_and_foreign_directories_are_reported(sim, written, tmp_path):
    with pytest.raises(DatasetError, match="no meta.json"):
        open_dataset(tmp_path)
    meta = json.loads((written / "meta.json").read_text())
    incomplete = tmp_path / "incomplete"
    incomplete.mkdir()
    (incomplete / "meta.json").write_text(json.dumps(dict(meta, complete=False)))
    with pytest.raises(DatasetError, match="incomplete"):
        open_dataset(incomplete)
    mixed = _copy_of(written, tmp_path / "mixed")
    (mixed / "meta.json").write_text(json.dumps(dict(meta, frame_count=13)))
    with pytest.raises(DatasetError, match="meta.json promises"):
        open_dataset(mixed)
    skin = load_sensor(scenes_directory().parent / "skin_3x3.yaml")
    with pytest.raises(DatasetError, match="made for sensor 'trueeb2020_4cam'"):
        open_dataset(written, skin)


@pytest.mark.parametrize("name, content, message", [
    ("contacts.json", None, "lacks contacts.json"),
    ("contacts.json", b"[[", "contacts.json is not readable UTF-8 JSON"),
    ("contacts.json", b"[]", "contacts of each of the 12 frames .* found 0 entries"),
    ("meta.json", b'{"format": "tactile_sim.dataset", "scene": "\xff"}', "meta.json is not readable UTF-8 JSON"),
    ("meta.json", {"complete": "no"}, "incomplete .*complete: 'no'"),
    ("meta.json", {"frame_count": 3.7}, "frame_count must be an integer >= 1, got 3.7"),
    ("meta.json", {"camera_ids": "cam0"}, "camera_ids must be a non-empty list"),
])
def test_bad_metadata_and_contacts_are_reported(written, tmp_path, name, content, message):
    broken = _copy_of(written, tmp_path / "broken")
    if content is None:
        (broken / name).unlink()
    elif isinstance(content, dict):
        (broken / name).write_text(json.dumps(dict(json.loads((written / name).read_text()), **content)))
    else:
        (broken / name).write_bytes(content)
    with pytest.raises(DatasetError, match=message):
        open_dataset(broken)
