"""The sensor description: one YAML file (config/sensor.yaml) read by every part of the stack.

The YAML is written for people (millimetres, kilopascals, micrometres, with the unit in the key); this module
validates it and converts it to SI units once, so that no other module parses the file or converts units.
Nothing here knows about ROS, so the simulator, the model and the nodes all use it alike.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import yaml

MM = 1e-3
KPA = 1e3
UM = 1e-6

#: Environment variable that names a sensor description to use instead of the installed default.
SENSOR_ENV = "TACTILE_SENSOR_CONFIG"


class SensorConfigError(ValueError):
    """A sensor description that is missing a key or holds an impossible value."""


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
        from ament_index_python.packages import PackageNotFoundError, get_package_share_directory
    except ImportError as exc:  # pragma: no cover - only without any ROS 2 Python packages
        raise SensorConfigError(f"no sensor description given: set {SENSOR_ENV} or install "
                                "ament_index_python and tactile_bringup") from exc
    try:
        share = get_package_share_directory("tactile_bringup")
    except PackageNotFoundError as exc:
        raise SensorConfigError(f"no sensor description given and tactile_bringup is not installed: "
                                f"source scripts/env.sh (after `make setup`) or set {SENSOR_ENV}") from exc
    return Path(share) / "config" / "sensor.yaml"


def load_sensor(path: str | os.PathLike | None = None) -> SensorDescription:
    """Read and validate a sensor description; `None` means the default one (see default_sensor_path)."""
    path = Path(path) if path is not None else default_sensor_path()
    try:
        raw = yaml.safe_load(path.read_text())
    except OSError as exc:
        raise SensorConfigError(f"cannot read sensor description {path}: {exc.strerror}") from exc
    except yaml.YAMLError as exc:
        raise SensorConfigError(f"sensor description {path} is not valid YAML: {exc}") from exc
    if not isinstance(raw, dict):
        raise SensorConfigError(f"sensor description {path} must be a mapping at the top level")
    return _parse(raw, str(path))


class _Reader:
    """Pulls typed, range-checked values out of nested YAML and names the key path in every error."""

    def __init__(self, source: str):
        self.source = source

    def get(self, node: dict, key: str, where: str):
        if not isinstance(node, dict) or key not in node:
            raise SensorConfigError(f"{self.source}: missing key {where}.{key}")
        return node[key]

    def number(self, node: dict, key: str, where: str, low: float = -math.inf, positive: bool = False) -> float:
        value = self.get(node, key, where)
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
            raise SensorConfigError(f"{self.source}: {where}.{key} must be a finite number, got {value!r}")
        if positive and value <= 0:
            raise SensorConfigError(f"{self.source}: {where}.{key} must be > 0, got {value}")
        if value < low:
            raise SensorConfigError(f"{self.source}: {where}.{key} must be >= {low}, got {value}")
        return float(value)

    def count(self, node: dict, key: str, where: str, low: int = 1) -> int:
        value = self.get(node, key, where)
        if isinstance(value, bool) or not isinstance(value, int) or value < low:
            raise SensorConfigError(f"{self.source}: {where}.{key} must be an integer >= {low}, got {value!r}")
        return value


def _parse(raw: dict, source: str) -> SensorDescription:
    r = _Reader(source)
    surface = r.get(raw, "surface", "")
    grid = BinGrid(
        rows=r.count(surface, "bin_rows", "surface"),
        cols=r.count(surface, "bin_cols", "surface"),
        width_m=r.number(surface, "width_mm", "surface", positive=True) * MM,
        length_m=r.number(surface, "length_mm", "surface", positive=True) * MM,
    )
    layers = []
    for i, node in enumerate(r.get(raw, "gel_layers", "") or []):
        where = f"gel_layers[{i}]"
        nu = r.number(node, "poisson_ratio", where, low=0.0)
        if nu >= 0.5:
            raise SensorConfigError(f"{source}: {where}.poisson_ratio must be < 0.5 (0.5 is incompressible and "
                                    f"makes the elastic kernels singular), got {nu}")
        layers.append(GelLayer(
            name=str(r.get(node, "name", where)),
            thickness_m=r.number(node, "thickness_mm", where, positive=True) * MM,
            youngs_modulus_pa=r.number(node, "youngs_modulus_kpa", where, positive=True) * KPA,
            poisson_ratio=nu,
        ))
    if not layers:
        raise SensorConfigError(f"{source}: gel_layers must list at least one layer")

    p = r.get(raw, "particles", "")
    diameters = r.get(p, "diameter_um", "particles")
    if not (isinstance(diameters, list) and len(diameters) == 2 and 0 < diameters[0] <= diameters[1]):
        raise SensorConfigError(f"{source}: particles.diameter_um must be [min, max] with 0 < min <= max")
    particles = ParticleSpec(
        layer=str(r.get(p, "layer", "particles")),
        diameter_min_m=float(diameters[0]) * UM,
        diameter_max_m=float(diameters[1]) * UM,
        per_m3=r.number(p, "per_mm3", "particles", positive=True) / MM**3,
        seed=r.count(p, "seed", "particles", low=0),
    )

    cams = r.get(raw, "cameras", "")
    capture = r.get(cams, "capture", "cameras")
    capture_size = (r.count(capture, "width", "cameras.capture"), r.count(capture, "height", "cameras.capture"))
    c = r.get(cams, "crop", "cameras")
    crop = Crop(r.count(c, "x", "cameras.crop", low=0), r.count(c, "y", "cameras.crop", low=0),
                r.count(c, "width", "cameras.crop"), r.count(c, "height", "cameras.crop"))
    if crop.x + crop.width > capture_size[0] or crop.y + crop.height > capture_size[1]:
        raise SensorConfigError(f"{source}: cameras.crop {crop} does not fit in the {capture_size} capture")
    out = r.get(cams, "output", "cameras")
    output_size = (r.count(out, "width", "cameras.output"), r.count(out, "height", "cameras.output"))
    lens_node = r.get(cams, "lens", "cameras")
    dist = r.get(lens_node, "distortion", "cameras.lens")
    if not (isinstance(dist, list) and len(dist) == 4):
        raise SensorConfigError(f"{source}: cameras.lens.distortion must list k1..k4")
    lens = FisheyeLens(
        fx=r.number(lens_node, "fx", "cameras.lens", positive=True),
        fy=r.number(lens_node, "fy", "cameras.lens", positive=True),
        cx=r.number(lens_node, "cx", "cameras.lens"),
        cy=r.number(lens_node, "cy", "cameras.lens"),
        distortion=tuple(float(k) for k in dist),
    )
    cameras = []
    for i, node in enumerate(r.get(cams, "units", "cameras") or []):
        where = f"cameras.units[{i}]"
        pos = r.get(node, "position_mm", where)
        if not (isinstance(pos, list) and len(pos) == 3):
            raise SensorConfigError(f"{source}: {where}.position_mm must be [x, y, z]")
        cameras.append(CameraSpec(
            camera_id=str(r.get(node, "id", where)),
            position_m=tuple(float(v) * MM for v in pos),
            yaw_rad=math.radians(r.number(node, "yaw_deg", where)),
            lens=lens,
            capture_size=capture_size,
            crop=crop,
            output_size=output_size,
        ))
    if not cameras:
        raise SensorConfigError(f"{source}: cameras.units must list at least one camera")
    ids = [cam.camera_id for cam in cameras]
    if len(set(ids)) != len(ids):
        raise SensorConfigError(f"{source}: camera ids must be unique, got {ids}")

    description = SensorDescription(
        name=str(r.get(raw, "name", "")),
        frame_id=str(r.get(raw, "frame_id", "")),
        grid=grid,
        gel_layers=tuple(layers),
        particles=particles,
        cameras=tuple(cameras),
        frame_rate_hz=r.number(cams, "frame_rate_hz", "cameras", positive=True),
        source=source,
    )
    description.layer(particles.layer)  # raises if the particle layer is not one of the gel layers
    for cam in cameras:
        if cam.position_m[2] > -description.gel_thickness_m:
            raise SensorConfigError(f"{source}: camera {cam.camera_id} at z = {cam.position_m[2] / MM} mm is "
                                    f"inside the gel (the gel spans 0 to {-description.gel_thickness_m / MM} mm)")
    return description
