import json
import subprocess

import numpy as np
import pytest

from tactile_description import load_sensor
from tactile_sim import DatasetError, SceneError, Simulator, load_scene, open_dataset, write_dataset
from tactile_sim.contact import contact_record
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
        assert ds.contacts()[f.index] == [contact_record(c) for c in f.contacts]  # as `tactile-sim press` gives one
    np.testing.assert_array_equal(ds.reference, sim.reference_images())
    assert isinstance(ds.images, np.memmap)
    meta = ds.meta
    assert meta["camera_ids"] == ["cam0", "cam1", "cam2", "cam3"] and meta["rows"] == 26 and meta["cols"] == 25
    assert meta["scene"] == "effects" and meta["frame_count"] == 12 and meta["complete"]
    assert len(ds.contacts()) == 12 and ds.contacts()[0][0]["shape"] == "Sphere"


def test_non_empty_output_is_not_overwritten_by_accident(sim, written):
    # the command line's option first: "pass overwrite=True (--overwrite)" spoke Python to a shell user
    with pytest.raises(DatasetError, match=r"not empty: it holds a data set; choose a new one or replace it with "
                                           r"--overwrite \(overwrite=True in Python\)"):
        write_dataset(sim, load_scene("effects"), written, progress=False, frames=2)


def test_overwrite_replaces_a_data_set_complete_or_not_and_keeps_the_other_files(sim, written, tmp_path):
    replaced = _copy_of(written, tmp_path / "replaced")
    meta = json.loads((replaced / "meta.json").read_text())
    (replaced / "meta.json").write_text(json.dumps(dict(meta, complete=False)))  # as a Ctrl-C leaves it
    (replaced / "notes.txt").write_text("kept")
    write_dataset(sim, load_scene("shear"), replaced, progress=False, frames=2, overwrite=True)
    ds = open_dataset(replaced, sim.sensor)
    assert len(ds) == 2 and ds.meta["scene"] == "shear" and ds.meta["complete"]
    assert (replaced / "notes.txt").read_text() == "kept"


@pytest.mark.parametrize("meta", [None, '{"format": "some_other_tool"}', "{"])
def test_overwrite_refuses_a_non_empty_directory_without_a_data_set(sim, tmp_path, meta):
    """Most likely the wrong directory (before: written into, its files of the data set's names replaced)."""
    (tmp_path / "images.npy").write_bytes(b"not a data set's")
    if meta is not None:
        (tmp_path / "meta.json").write_text(meta)
    before = {f.name: f.read_bytes() for f in tmp_path.iterdir()}
    with pytest.raises(DatasetError, match=f"output directory {tmp_path} is not empty and holds no data set .*; choose "
                                           r"a new or empty one \(overwrite, --overwrite, replaces a data set only\)"):
        write_dataset(sim, load_scene("effects"), tmp_path, progress=False, frames=2, overwrite=True)
    assert {f.name: f.read_bytes() for f in tmp_path.iterdir()} == before


def test_a_scene_that_does_not_fit_the_sensor_leaves_no_directory(sim, tmp_path):
    scene_file = tmp_path / "other_cameras.yaml"
    effects = (scenes_directory() / "effects.yaml").read_text()
    scene_file.write_text(effects.replace("cameras: [cam1]", "cameras: [cam9]"))
    with pytest.raises(SceneError, match="cam9"):
        write_dataset(sim, load_scene(scene_file), tmp_path / "out", progress=False, frames=2)
    assert not (tmp_path / "out").exists()


def test_the_first_frames_of_a_scene_whose_later_random_presses_find_no_room_are_written(sim, tmp_path):
    """`generate --frames 2` of multi_contact on a 24.5 mm strip: its random presses (frames 2 on) find no room there,
    and the whole scene was checked, not the frames asked for (found in review)."""
    import dataclasses

    strip = dataclasses.replace(sim.sensor, grid=dataclasses.replace(sim.sensor.grid, width_m=24.5e-3))
    narrow = Simulator(strip)
    with pytest.raises(SceneError, match="found room for only"):
        write_dataset(narrow, load_scene("multi_contact"), tmp_path / "all", progress=False)
    assert not (tmp_path / "all").exists()
    assert len(open_dataset(write_dataset(narrow, load_scene("multi_contact"), tmp_path / "two", progress=False,
                                          frames=2), strip)) == 2


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
    (broken / "images.npy").write_bytes(b"")  # numpy's EOFError went through as a traceback (walkthrough)
    with pytest.raises(DatasetError, match=r"images.npy is corrupt or truncated \(No data left in file\)"):
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
    damaged = _copy_of(written, tmp_path / "damaged")
    (damaged / "meta.json").write_text(json.dumps(dict(meta, sensor={"grid": {}})))
    with pytest.raises(DatasetError, match=r"meta.json: sensor \(the description it was made for\): lacks "
                                           r"\['gel_layers', 'particles', 'cameras'\]; regenerate the data set"):
        open_dataset(damaged, sim.sensor)
    open_dataset(damaged)  # without a sensor to check it against, it is not read


@pytest.mark.parametrize("name, content, message", [
    ("contacts.json", None, "lacks contacts.json"),
    ("contacts.json", b"[[", "contacts.json is not readable UTF-8 JSON"),
    ("contacts.json", b"[]", "contacts of each of the 12 frames .* found 0 entries"),
    ("meta.json", b'{"format": "tactile_sim.dataset", "scene": "\xff"}', "meta.json is not readable UTF-8 JSON"),
    ("meta.json", {"complete": "no"}, "incomplete .*complete: 'no'"),
    ("meta.json", {"frame_count": 3.7}, "frame_count must be an integer >= 1, got 3.7"),
    ("meta.json", {"camera_ids": "cam0"}, "camera_ids must be a non-empty list"),
    # tactile-fusion ended in a KeyError or numpy's error splitting the frames (found in review)
    ("meta.json", {"seed": None}, "scene must be a name and seed a whole number >= 0, got 'effects' and None"),
    ("meta.json", {"seed": -5}, "seed a whole number >= 0, got 'effects' and -5"),
    ("meta.json", {"scene": 3}, "scene must be a name and seed a whole number >= 0, got 3 and"),
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


@pytest.fixture
def small_disk(tmp_path):
    """A 2 MB file system (tmpfs) at tmp_path/disk, unmounted afterwards. Mounting needs root (CAP_SYS_ADMIN), which
    `make test` has in this project's CI; elsewhere the test is skipped, saying why."""
    disk = tmp_path / "disk"
    disk.mkdir()
    mounted = subprocess.run(["mount", "-t", "tmpfs", "-o", "size=2m", "tmpfs", str(disk)], capture_output=True,
                             text=True)
    if mounted.returncode != 0:
        pytest.skip(f"cannot mount a small tmpfs here (needs root): {mounted.stderr.strip()}")
    try:
        yield disk
    finally:
        subprocess.run(["umount", str(disk)], check=True)


def test_a_disk_that_fills_is_an_error_naming_the_file_not_a_bus_error(sim, small_disk):
    """The frame arrays were sparse memory-mapped files: writing frames on a full disk killed the process with SIGBUS
    ("Bus error", exit 135, no message). Their space is reserved now, so the disk is found full at once."""
    with pytest.raises(OSError, match="No space left on device") as refused:
        write_dataset(sim, load_scene("demo", sim.sensor), small_disk / "data", progress=False, frames=100)
    assert refused.value.filename == str(small_disk / "data" / "images.npy")
    assert json.loads((small_disk / "data" / "meta.json").read_text())["complete"] is False
