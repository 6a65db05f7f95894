import ast
import inspect
import tempfile
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from ament_index_python.packages import get_package_prefix, get_package_share_directory

from tactile_bringup.graph import NodeSpec, camera_sources, sensor_graph
from tactile_bringup.rviz_config import grid_display, rviz_config, write_rviz_config
from tactile_conversions.topics import graph_namespace
from tactile_description import default_sensor_path, load_sensor

SHARE = Path(get_package_share_directory("tactile_bringup"))


@pytest.fixture(scope="module")
def sensor():
    return load_sensor()


def test_simulated_graph_runs_cameras_bundle_and_fusion(sensor):
    specs = sensor_graph(sensor, str(default_sensor_path()), "sim", scene="demo", model_dir="/models/x")
    assert [s.executable for s in specs] == ["sim_camera_node", "bundle_node", "fusion_node"]
    assert specs[0].parameters["scene"] == "demo"
    # the scene plays once the bundle node and the fusion node, which loads its model first, listen (sim_camera_node)
    assert specs[0].parameters["wait_for_nodes"] == f"{specs[1].name},{specs[2].name}"
    assert specs[2].parameters["model_dir"] == "/models/x"
    assert all(s.parameters["sensor_config"] == str(default_sensor_path()) for s in specs)


def test_every_executable_of_the_graph_is_installed(sensor):
    sources_file = str(SHARE / "config" / "camera_sources.yaml")
    for source, extra in (("sim", {}), ("cameras", {"camera_sources_file": sources_file})):
        for spec in sensor_graph(sensor, "", source, **extra):
            executable = Path(get_package_prefix(spec.package)) / "lib" / spec.package / spec.executable
            assert executable.exists(), executable


def test_real_cameras_get_one_driver_each(sensor):
    specs = sensor_graph(sensor, "", "cameras", camera_sources_file=str(SHARE / "config" / "camera_sources.yaml"))
    drivers = [s for s in specs if s.executable == "camera_node"]
    assert [s.parameters["camera_id"] for s in drivers] == list(sensor.camera_ids)
    assert len({s.name for s in specs}) == len(specs)


def test_camera_sources_must_cover_every_camera(sensor, tmp_path):
    partial = tmp_path / "sources.yaml"
    partial.write_text("cam0: /dev/video0\n")
    with pytest.raises(ValueError, match=r"no source for cameras \['cam1', 'cam2', 'cam3'\]"):
        camera_sources(partial, sensor)


def test_a_camera_sources_file_that_is_not_yaml_text_is_refused_naming_it(sensor, tmp_path):
    sources = tmp_path / "sources.yaml"
    sources.write_bytes(b"cam0: \xf0\x28\x8c\x28\n")
    with pytest.raises(ValueError, match=rf"camera sources file {sources} is not UTF-8 text"):
        camera_sources(sources, sensor)
    with pytest.raises(ValueError, match=rf"cannot read camera sources file {tmp_path / 'none.yaml'}"):
        camera_sources(tmp_path / "none.yaml", sensor)


def test_a_camera_source_left_empty_is_refused_not_taken_as_the_text_none(sensor, tmp_path):
    sources = tmp_path / "sources.yaml"
    sources.write_text("cam0: 0\ncam1:\ncam2: ''\ncam3: /dev/video3\n")
    with pytest.raises(ValueError, match=r"cameras \['cam1', 'cam2'\] have no source"):
        camera_sources(sources, sensor)
    sources.write_text("cam0: 0\ncam1: 1\ncam2: /dev/video2\ncam3: clip.mp4\n")
    assert camera_sources(sources, sensor) == {"cam0": "0", "cam1": "1", "cam2": "/dev/video2", "cam3": "clip.mp4"}


def test_bad_source_is_rejected(sensor):
    with pytest.raises(ValueError, match="source must be one of"):
        sensor_graph(sensor, "", "webcam")
    with pytest.raises(ValueError, match="needs a camera sources file"):
        sensor_graph(sensor, "", "cameras")


def test_parameters_become_ros_arguments():
    spec = NodeSpec("pkg", "exe", "my_node", {"scene": "demo", "loop": True, "rate_hz": 40.0, "model_dir": "",
                                              "name": "it's"})
    assert spec.ros_arguments() == ["--ros-args", "-r", "__node:=my_node", "-p", "scene:='demo'", "-p", "loop:=true",
                                    "-p", "rate_hz:=40.0", "-p", "model_dir:=''", "-p", "name:='it''s'"]
    for namespace in ("/left", "left"):  # rcl takes only an absolute __ns
        assert replace(spec, parameters={}, namespace=namespace).ros_arguments() == [
            "--ros-args", "-r", "__node:=my_node", "-r", "__ns:=/left"]


def test_a_graph_in_a_namespace_has_every_node_there_and_a_bad_namespace_is_refused(sensor):
    sources_file = str(SHARE / "config" / "camera_sources.yaml")
    for given, namespace in (("", "/"), ("/", "/"), ("left", "/left"), ("/left/", "/left"),
                             ("robot/left", "/robot/left")):
        for source, extra in (("sim", {}), ("cameras", {"camera_sources_file": sources_file})):
            specs = sensor_graph(sensor, "", source, namespace=given, **extra)
            assert {s.namespace for s in specs} == {namespace}, (given, source)
    # Within a namespace that a launch file including sensor.launch.py pushed, as ROS puts a relative name there.
    for given, parent, namespace in (("left", "/robot", "/robot/left"), ("", "/robot", "/robot"),
                                     ("/left", "/robot", "/left"), ("left", "/", "/left")):
        assert graph_namespace(given, parent) == namespace
    for bad, reason in (("1st", "must not have a token that starts with a number"),
                        ("left arm", "must not contain characters other than alphanumerics"),
                        ("robot//left", "must not contain repeated '/'")):
        with pytest.raises(ValueError, match=f"namespace '{bad}': not a ROS namespace \\(namespace {reason}"):
            sensor_graph(sensor, "", "sim", namespace=bad)


def test_installed_launch_file_builds_the_graph_from_this_module():
    """The launch system is not installable here (see docs/ros2-from-pypi.md): check what can be checked."""
    source = (SHARE / "launch" / "sensor.launch.py").read_text()
    tree = ast.parse(source)
    functions = {node.name for node in ast.walk(tree) if isinstance(node, ast.FunctionDef)}
    assert "generate_launch_description" in functions
    assert "from tactile_bringup.graph import sensor_graph" in source
    # Its call of sensor_graph gives each launch argument to the parameter of that name (checked against the
    # signature, so that reordering the parameters cannot go unnoticed; found in an audit of the tests).
    call = next(node for node in ast.walk(tree) if isinstance(node, ast.Call)
                and getattr(node.func, "id", None) == "sensor_graph")
    given = [arg.slice.value if isinstance(arg, ast.Subscript) else arg.id for arg in call.args]
    parameters = list(inspect.signature(sensor_graph).parameters)
    assert len(given) == len(parameters) and not call.keywords
    launch_name = {"camera_sources_file": "camera_sources"}  # the launch argument of that parameter
    assert given == [launch_name.get(name, name) for name in parameters], given
    # RViz gets the configuration written for the sensor description the graph runs, not a fixed file.
    rviz = next(node for node in ast.walk(tree) if isinstance(node, ast.Call)
                and getattr(node.func, "id", None) == "write_rviz_config")
    assert getattr(rviz.args[0], "id", None) == "sensor" and len(rviz.args) == 1  # no path: under ROS_HOME
    assert [(k.arg, getattr(k.value, "id", None)) for k in rviz.keywords] == [("namespace", "namespace")]
    # Every node, RViz too, runs in the graph's namespace: one that did not would publish or look beside it. That
    # namespace is absolute, so it must hold what an including launch file pushed (launch_ros keeps it as the launch
    # configuration ros_namespace, and puts a node given an absolute namespace outside it).
    nodes = [node for node in ast.walk(tree) if isinstance(node, ast.Call) and getattr(node.func, "id", None) == "Node"]
    assert len(nodes) == 2 and all("namespace" in [k.arg for k in node.keywords] for node in nodes)
    assert 'graph_namespace(value["namespace"], context.launch_configurations.get("ros_namespace") or "/")' in source
    assert 'load_sensor(value["sensor_config"])' in source and '"config" / "tactile.rviz"' not in source
    for path in ("config/sensor.yaml", "config/camera_sources.yaml", "config/tactile.rviz"):
        assert (SHARE / path).exists(), path


def test_latency_measures_the_graph_with_its_markers_rate_and_without_stamp_jitter(sensor):
    from tactile_bringup.latency import FUSION_THREADS, measured_spec

    specs = {s.executable: measured_spec(s, 40.0)
             for s in sensor_graph(sensor, str(default_sensor_path()), "sim", scene="demo")}
    assert specs["fusion_node"].parameters["markers_rate_hz"] == 40.0
    assert specs["fusion_node"].parameters["threads"] == FUSION_THREADS
    assert specs["sim_camera_node"].parameters["stamp_jitter_s"] == 0.0
    assert "markers_rate_hz" not in specs["bundle_node"].parameters


def test_rviz_config_shows_the_topics_the_fusion_node_publishes(sensor):
    """RViz cannot run here: check that its displays name the topics the graph publishes, with matching types."""
    from tactile_conversions.forces import MARKER_NAMESPACE
    from tactile_conversions.topics import MARKERS_TOPIC, WRENCH_TOPIC

    displays = rviz_config(sensor)["Visualization Manager"]["Displays"]
    topics = {d["Class"]: d["Topic"]["Value"] for d in displays if "Topic" in d}
    assert topics == {"rviz_default_plugins/MarkerArray": MARKERS_TOPIC, "rviz_default_plugins/Wrench": WRENCH_TOPIC}
    for namespace in ("/left", "left"):
        displays = rviz_config(sensor, namespace)["Visualization Manager"]["Displays"]
        assert {d["Topic"]["Value"] for d in displays if "Topic" in d} == {"/left" + MARKERS_TOPIC,
                                                                           "/left" + WRENCH_TOPIC}
    markers = next(d for d in displays if d["Class"] == "rviz_default_plugins/MarkerArray")
    assert markers["Namespaces"] == {MARKER_NAMESPACE: True}


def test_the_installed_rviz_config_is_the_reference_sensors():
    """config/tactile.rviz, for RViz opened without the launch system, is what the launch file writes for the
    reference sensor (regenerate it with write_rviz_config after a change): config/sensor.yaml, named here, not
    TACTILE_SENSOR_CONFIG's description."""
    import yaml

    reference = load_sensor(SHARE / "config" / "sensor.yaml")
    assert yaml.safe_load((SHARE / "config" / "tactile.rviz").read_text()) == rviz_config(reference)


def test_rviz_shows_the_sensor_in_its_own_frame(sensor, tmp_path):
    """A sensor in another frame: with the reference sensor's fixed frame RViz would show none of its markers."""
    import yaml

    pad = replace(sensor, frame_id="left_finger_pad")
    written = yaml.safe_load(write_rviz_config(pad, tmp_path / "pad.rviz").read_text())
    assert written["Visualization Manager"]["Global Options"]["Fixed Frame"] == "left_finger_pad"
    assert written == rviz_config(pad)


def test_each_launch_of_a_sensor_writes_its_rviz_config_to_one_file_under_ros_home(sensor, tmp_path, monkeypatch):
    """sensor.launch.py rviz:=true made a temporary directory at every launch and left it behind (review)."""
    import yaml

    monkeypatch.setenv("ROS_HOME", str(tmp_path))
    first = write_rviz_config(sensor)
    assert write_rviz_config(sensor) == first and first.parent == tmp_path / "tactile_bringup"
    pad = replace(sensor, frame_id="left_finger_pad")
    assert yaml.safe_load(write_rviz_config(pad).read_text()) == rviz_config(pad)
    assert yaml.safe_load(first.read_text()) == rviz_config(sensor)
    assert len(list(first.parent.iterdir())) == 2  # one file per sensor, nothing left beside them


def test_an_unwritable_ros_home_gives_rvizs_config_a_temporary_directory(sensor, tmp_path, monkeypatch):
    """mkdir under a ROS_HOME that is a file failed inside the launch file: the whole graph did not start (review)."""
    import yaml

    (tmp_path / "ros_home").write_text("a file")
    monkeypatch.setenv("ROS_HOME", str(tmp_path / "ros_home"))
    (tmp_path / "tmp").mkdir()
    monkeypatch.setattr(tempfile, "tempdir", str(tmp_path / "tmp"))  # the system's temporary directory, here
    written = write_rviz_config(sensor)
    assert written.parent.parent == tmp_path / "tmp" and written.parent.name.startswith("tactile_bringup_")
    assert yaml.safe_load(written.read_text()) == rviz_config(sensor)


def test_a_config_that_cannot_be_written_leaves_nothing_beside_its_path(sensor, tmp_path):
    (tmp_path / "taken.rviz").mkdir()  # os.replace cannot put a file there
    with pytest.raises(OSError):
        write_rviz_config(sensor, tmp_path / "taken.rviz")
    assert [p.name for p in tmp_path.iterdir()] == ["taken.rviz"]


@pytest.mark.parametrize("sensor_file", ["sensor.yaml", "skin_3x3.yaml"])
def test_the_rviz_grid_lines_fall_on_the_bin_edges(sensor_file):
    """RViz draws a Grid's lines at offset - count * size / 2 + i * size, i = 0..count (rviz_rendering's
    Grid::createGridPlane). Its offset put the x lines on the columns' centres, half a bin off (found in review).
    The lines must cover the whole surface, of the reference sensor and of the nine-camera skin."""
    grid = load_sensor(SHARE / "config" / sensor_file).grid
    bins = grid_display(load_sensor(SHARE / "config" / sensor_file))
    size, count = bins["Cell Size"], bins["Plane Cell Count"]
    for axis, edges in (("X", np.arange(grid.cols + 1) * grid.width_m / grid.cols),
                        ("Y", np.arange(grid.rows + 1) * grid.length_m / grid.rows)):
        lines = bins["Offset"][axis] - count * size / 2 + np.arange(count + 1) * size
        assert np.abs(lines[:, None] - edges[None, :]).min(axis=0).max() < 5e-5, axis  # every edge within 0.05 mm


def test_the_rviz_grid_covers_a_surface_of_long_narrow_bins(sensor):
    """Ten bins of 1 x 10 mm each way over 10 x 100 mm: a grid of ten 1 mm cells covered a tenth of its length
    (review). Its lines are the columns' edges along x, and they reach the far end along y."""
    strip = replace(sensor, grid=replace(sensor.grid, rows=10, cols=10, width_m=0.01, length_m=0.1))
    bins = grid_display(strip)
    size, count, offset = bins["Cell Size"], bins["Plane Cell Count"], bins["Offset"]
    lines = -count * size / 2 + np.arange(count + 1) * size
    assert np.allclose((offset["X"] + lines)[:11], np.arange(11) * 1e-3)
    assert (offset["Y"] + lines).max() >= 0.1 - 1e-9 and (offset["Y"] + lines).min() == pytest.approx(0.0)
