"""The sensor description: one YAML file (config/sensor.yaml) read by every part of the stack.

The YAML is written for people (millimetres, kilopascals, micrometres, with the unit in the key); this module
validates it and converts it to SI units once, so that no other module parses the file or converts units.
Nothing here knows about ROS, so the simulator, the model and the nodes all use it alike.
"""

from __future__ import annotations

import math
import os
import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from tactile_description.yaml_fields import YamlFields, load_yaml_file

MM = 1e-3
KPA = 1e3
UM = 1e-6

#: Environment variable that names a sensor description to use instead of the installed default.
SENSOR_ENV = "TACTILE_SENSOR_CONFIG"

#: Widest or tallest capture image, pixels (a 4K camera's width). The crop lies inside the capture and the output
#: image is the crop area-downsampled (tactile_description.imaging), so this bounds all three: a larger value is a
#: typo that would only end in a failed allocation of the simulator's image buffers.
MAX_IMAGE_SIDE_PX = 4096


#: The most bins and particles a sensor description may give, 25 and 130 times the reference sensor's 650 and 7497: a
#: larger value is a typo (bin_rows: 2600000000, per_mm3: 1.0e9) that ended in a traceback of a failed allocation of
#: terabytes in the simulator.
MAX_BINS = 16384
MAX_PARTICLES = 1_000_000


#: The camera frame rates a sensor description may give, one frame a day to 1 kHz, and so the rates the camera nodes'
#: `rate_hz` takes (tactile_conversions.parameters): a rate of the description beyond them was refused by the nodes as
#: if the user had set `rate_hz` (found in review). The sensor's cameras run at 40 Hz, a fast USB camera at a few
#: hundred; above 1 kHz is a typo, and a node could not keep it anyway (a simulated frame takes milliseconds).
MIN_FRAME_RATE_HZ = 1.0 / 86_400.0
MAX_FRAME_RATE_HZ = 1000.0

#: A camera id names the camera's topic (/tactile/<id>/image), node and frame: a ROS name token, as rcl validates
#: one. `cam-0`, `cam.0` or a YAML number `0` ended every camera node in a traceback (found in review); so did an id
#: of 300 characters, over rcl's 247 for a topic (review): at most 64.
CAMERA_ID = re.compile(r"[A-Za-z_][A-Za-z0-9_]{0,63}")

#: The ranges of the gel's and the surface's sizes and stiffness: a sensor's are millimetres to centimetres and kPa
#: to MPa. A finite number beyond them, a typo, overflowed: a Young's modulus of 1e306 kPa became inf Pa, a layer
#: 1e308 mm thick left the particle layer no volume, and the description's check divided by it (review).
SURFACE_SIDE_MM = (0.1, 10_000.0)
LAYER_THICKNESS_MM = (0.001, 1000.0)
YOUNGS_MODULUS_KPA = (0.001, 1e9)


class SensorConfigError(ValueError):
    """A sensor description that is missing a key or holds an impossible value."""


#: The components of a bin's force, in the order of every force array (rows, cols, 3) and of the messages:
#: tangential along +x and +y, normal (positive in compression).
FORCE_COMPONENTS = ("fx", "fy", "fz")


def left_out_components(components) -> tuple[str, ...]:
    """The force components not among `components`: those an estimate carrying these outputs as exact zeros."""
    return tuple(c for c in FORCE_COMPONENTS if c not in components)


@dataclass(frozen=True)
class BinGrid:
    """The surface divided into rows x cols bins of equal area; row along y, column along x."""

    rows: int
    cols: int
    width_m: float   # surface extent along x
    length_m: float  # surface extent along y

    @property
    def bin_width_m(self) -> float:
        return self.width_m / self.cols

    @property
    def bin_length_m(self) -> float:
        return self.length_m / self.rows

    @property
    def n_bins(self) -> int:
        return self.rows * self.cols

    @property
    def centre_m(self) -> tuple[float, float]:
        """(x, y) of the middle of the surface."""
        return 0.5 * self.width_m, 0.5 * self.length_m

    def bin_centers_m(self) -> np.ndarray:
        """(rows, cols, 2) array of bin centre (x, y) in metres."""
        x = (np.arange(self.cols) + 0.5) * self.bin_width_m
        y = (np.arange(self.rows) + 0.5) * self.bin_length_m
        xx, yy = np.meshgrid(x, y)
        return np.stack([xx, yy], axis=-1)


@dataclass(frozen=True)
class GelLayer:
    name: str
    thickness_m: float
    youngs_modulus_pa: float
    poisson_ratio: float


@dataclass(frozen=True)
class ParticleSpec:
    layer: str
    diameter_min_m: float
    diameter_max_m: float
    per_m3: float
    seed: int


@dataclass(frozen=True)
class FisheyeLens:
    """OpenCV fisheye model in capture pixels: K = [[fx, 0, cx], [0, fy, cy], [0, 0, 1]], D = k1..k4."""

    fx: float
    fy: float
    cx: float
    cy: float
    distortion: tuple[float, float, float, float]

    @property
    def camera_matrix(self) -> np.ndarray:
        return np.array([[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]])

    @property
    def distortion_coefficients(self) -> np.ndarray:
        return np.array(self.distortion, dtype=np.float64).reshape(4, 1)


@dataclass(frozen=True)
class Crop:
    x: int
    y: int
    width: int
    height: int


@dataclass(frozen=True)
class CameraSpec:
    """One camera under the surface. It looks along +z; yaw turns its image about the optical axis."""

    camera_id: str
    position_m: tuple[float, float, float]
    yaw_rad: float
    lens: FisheyeLens
    capture_size: tuple[int, int]  # (width, height) in pixels
    crop: Crop
    output_size: tuple[int, int]   # (width, height) in pixels, what the model sees


@dataclass(frozen=True)
class SensorDescription:
    name: str
    frame_id: str
    grid: BinGrid
    gel_layers: tuple[GelLayer, ...]
    particles: ParticleSpec
    cameras: tuple[CameraSpec, ...]
    frame_rate_hz: float
    source: str = ""

    @property
    def camera_ids(self) -> tuple[str, ...]:
        return tuple(c.camera_id for c in self.cameras)

    @property
    def n_cameras(self) -> int:
        return len(self.cameras)

    @property
    def gel_thickness_m(self) -> float:
        return sum(layer.thickness_m for layer in self.gel_layers)

    @property
    def particle_layer_volume_m3(self) -> float:
        top, bottom = self.layer_depth_range_m(self.particles.layer)
        return self.grid.width_m * self.grid.length_m * (bottom - top)

    @property
    def particle_count(self) -> int:
        """The particles in the particle layer: its volume times the density, rounded (not a random draw); the
        description is refused where that is beyond MAX_PARTICLES, infinite included."""
        return int(round(self.particles.per_m3 * self.particle_layer_volume_m3))

    def layer(self, name: str) -> GelLayer:
        for layer in self.gel_layers:
            if layer.name == name:
                return layer
        raise SensorConfigError(f"{self.source}: no gel layer named {name!r}; layers are "
                                f"{[layer.name for layer in self.gel_layers]}")

    def layer_depth_range_m(self, name: str) -> tuple[float, float]:
        """(top, bottom) depth below the surface of a gel layer, both >= 0 (layers listed bottom to top)."""
        depth = 0.0
        for layer in reversed(self.gel_layers):
            if layer.name == name:
                return depth, depth + layer.thickness_m
            depth += layer.thickness_m
        raise SensorConfigError(f"{self.source}: no gel layer named {name!r}")


def default_sensor_path() -> Path:
    """The description to use when none is named: $TACTILE_SENSOR_CONFIG, else the installed tactile_bringup one."""
    override = os.environ.get(SENSOR_ENV)
    if override:
        return Path(override)
    try:
        return installed_config_dir() / "sensor.yaml"
    except SensorConfigError as exc:
        raise SensorConfigError(f"no sensor description given, and {exc}; or set {SENSOR_ENV}") from exc


def installed_config_dir() -> Path:
    """tactile_bringup's installed config directory: the default sensor description and the simulator's scenes.
    SensorConfigError where tactile_bringup is not installed."""
    try:
        from ament_index_python.packages import PackageNotFoundError, get_package_share_directory
    except ImportError as exc:  # pragma: no cover - only without any ROS 2 Python packages
        raise SensorConfigError("ament_index_python, which finds tactile_bringup's config, is not installed") from exc
    try:
        share = get_package_share_directory("tactile_bringup")
    except PackageNotFoundError as exc:
        raise SensorConfigError("tactile_bringup, which installs the default sensor description and the scenes, is "
                                "not installed: source scripts/env.sh (after `make setup`)") from exc
    return Path(share) / "config"


def load_sensor(path: str | os.PathLike | None = None) -> SensorDescription:
    """Read and validate a sensor description; `None` means the default one (see default_sensor_path)."""
    path = Path(path) if path is not None else default_sensor_path()
    raw = load_yaml_file(path, "sensor description", SensorConfigError)
    if not isinstance(raw, dict):
        raise SensorConfigError(f"sensor description {path} must be a mapping at the top level")
    return _parse(raw, str(path))


def _fields(node, where: str) -> YamlFields:
    return YamlFields(node, where, SensorConfigError)


def _text(fields: YamlFields, key: str) -> str:
    """A required key whose value is a non-empty text: a YAML null was the frame "None", a list a layer "['a', 'b']"
    (found in reviews)."""
    value = fields.raw(key, required=True)
    if not (isinstance(value, str) and value.strip()):
        raise SensorConfigError(f"{fields.where}.{key} must be a non-empty text, got {value!r}")
    return value


def _parse(raw: dict, source: str) -> SensorDescription:
    top = _fields(raw, source)
    surface = top.child("surface")
    grid = BinGrid(rows=surface.count("bin_rows"), cols=surface.count("bin_cols"),
                   width_m=surface.number("width_mm", low=SURFACE_SIDE_MM[0], high=SURFACE_SIDE_MM[1]) * MM,
                   length_m=surface.number("length_mm", low=SURFACE_SIDE_MM[0], high=SURFACE_SIDE_MM[1]) * MM)
    surface.finish()
    if grid.rows * grid.cols > MAX_BINS:
        raise SensorConfigError(f"{source}: surface {grid.rows} x {grid.cols} bins is more than {MAX_BINS} bins; give "
                                "the sensor's real bin grid")

    layer_nodes = top.raw("gel_layers", required=True)
    if not isinstance(layer_nodes, list) or not layer_nodes:
        raise SensorConfigError(f"{source}: gel_layers must list at least one layer")
    layers = []
    for i, node in enumerate(layer_nodes):
        f = _fields(node, f"{source}.gel_layers[{i}]")
        layers.append(GelLayer(name=_text(f, "name"),
                               thickness_m=f.number("thickness_mm", low=LAYER_THICKNESS_MM[0],
                                                    high=LAYER_THICKNESS_MM[1]) * MM,
                               youngs_modulus_pa=f.number("youngs_modulus_kpa", low=YOUNGS_MODULUS_KPA[0],
                                                          high=YOUNGS_MODULUS_KPA[1]) * KPA,
                               # below 0.5: an incompressible layer makes the elastic kernels singular
                               poisson_ratio=f.number("poisson_ratio", low=0.0, high=0.4999)))
        f.finish()
    names = [layer.name for layer in layers]
    if len(set(names)) != len(names):
        raise SensorConfigError(f"{source}: gel_layers[*].name must be unique (particles.layer names one), got {names}")

    p = top.child("particles")
    diameter_min_um, diameter_max_um = p.span("diameter_um", low=1e-9)
    particles = ParticleSpec(layer=_text(p, "layer"), diameter_min_m=diameter_min_um * UM,
                             diameter_max_m=diameter_max_um * UM, per_m3=p.number("per_mm3", positive=True) / MM**3,
                             seed=p.count("seed", low=0))
    p.finish()

    cams = top.child("cameras")
    capture, c, out, lens_node = cams.child("capture"), cams.child("crop"), cams.child("output"), cams.child("lens")
    capture_size = (capture.count("width"), capture.count("height"))
    if max(capture_size) > MAX_IMAGE_SIDE_PX:
        raise SensorConfigError(f"{source}: cameras.capture {capture_size[0]} x {capture_size[1]} px is larger than "
                                f"{MAX_IMAGE_SIDE_PX} px on a side; give the camera's real image size")
    crop = Crop(c.count("x", low=0), c.count("y", low=0), c.count("width"), c.count("height"))
    if crop.x + crop.width > capture_size[0] or crop.y + crop.height > capture_size[1]:
        raise SensorConfigError(f"{source}: cameras.crop {crop} does not fit in the {capture_size} capture")
    output_size = (out.count("width"), out.count("height"))
    if output_size[0] > crop.width or output_size[1] > crop.height:  # INTER_AREA would upsample, adding no detail
        raise SensorConfigError(f"{source}: cameras.output {output_size[0]} x {output_size[1]} px is larger than the "
                                f"{crop.width} x {crop.height} px crop it is downsampled from; make it at most that")
    lens = FisheyeLens(fx=lens_node.number("fx", positive=True), fy=lens_node.number("fy", positive=True),
                       cx=lens_node.number("cx"), cy=lens_node.number("cy"),
                       distortion=lens_node.numbers("distortion", 4))
    for f in (capture, c, out, lens_node):
        f.finish()
    unit_nodes = cams.raw("units", required=True)
    if not isinstance(unit_nodes, list) or not unit_nodes:
        raise SensorConfigError(f"{source}: cameras.units must list at least one camera")
    cameras = []
    for i, node in enumerate(unit_nodes):
        f = _fields(node, f"{source}.cameras.units[{i}]")
        camera_id = f.raw("id", required=True)
        if not (isinstance(camera_id, str) and CAMERA_ID.fullmatch(camera_id)):
            raise SensorConfigError(f"{source}.cameras.units[{i}]: id {camera_id!r} cannot name the camera's ROS topic "
                                    f"(/tactile/<id>/image): use up to 64 letters, digits and underscores, not "
                                    f"starting with a digit, e.g. cam{i}")
        cameras.append(CameraSpec(camera_id=camera_id,
                                  position_m=tuple(v * MM for v in f.numbers("position_mm", 3)),
                                  yaw_rad=math.radians(f.number("yaw_deg")), lens=lens, capture_size=capture_size,
                                  crop=crop, output_size=output_size))
        f.finish()
    ids = [cam.camera_id for cam in cameras]
    if len(set(ids)) != len(ids):
        raise SensorConfigError(f"{source}: camera ids must be unique, got {ids}")
    frame_rate_hz = cams.number("frame_rate_hz", low=MIN_FRAME_RATE_HZ, high=MAX_FRAME_RATE_HZ)
    cams.finish()

    frame_id = _text(top, "frame_id")
    if frame_id.startswith("/"):  # tf2 refuses it (BufferCore::validateFrameId)
        raise SensorConfigError(f"{source}.frame_id must be a tf2 frame name, without a leading '/', got {frame_id!r}")
    description = SensorDescription(name=_text(top, "name"), frame_id=frame_id, grid=grid,
                                    gel_layers=tuple(layers), particles=particles, cameras=tuple(cameras),
                                    frame_rate_hz=frame_rate_hz, source=source)
    top.finish()
    description.layer(particles.layer)  # raises if the particle layer is not one of the gel layers
    particles_in_layer = particles.per_m3 * description.particle_layer_volume_m3  # inf for 1e300 per mm^3: checked
    if particles_in_layer > MAX_PARTICLES:  # before it is rounded (OverflowError, a traceback: found in review)
        raise SensorConfigError(f"{source}: particles.per_mm3 = {particles.per_m3 * MM**3:g} puts "
                                f"{particles_in_layer:.3g} particles in the "
                                f"{description.particle_layer_volume_m3 / MM**3:.4g} mm^3 of layer "
                                f"{particles.layer!r}, more than {MAX_PARTICLES}; give the gel's real particle density "
                                "and size")
    if description.particle_count < 1:
        volume_mm3 = description.particle_layer_volume_m3 / MM**3
        raise SensorConfigError(f"{source}: particles.per_mm3 = {particles.per_m3 * MM**3:g} puts no particle in the "
                                f"{volume_mm3:.4g} mm^3 of layer {particles.layer!r}; the cameras would see nothing: "
                                f"use at least {0.5 / volume_mm3:.3g} per mm^3")
    for cam in cameras:
        if cam.position_m[2] > -description.gel_thickness_m:
            raise SensorConfigError(f"{source}: camera {cam.camera_id} at z = {cam.position_m[2] / MM} mm is "
                                    f"inside the gel (the gel spans 0 to {-description.gel_thickness_m / MM} mm)")
    return description
