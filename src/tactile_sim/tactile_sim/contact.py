"""Indenters, contacts and the ground-truth force per bin (the labels the sensor learns).

Note for cli.py: `tactile-sim press ... --json` prints `press_report(sensor, contact, model)` (json.dumps of it);
build the contact with `press_contact(...)` from the command-line values and the model with
`ground_truth_model(sensor, args.model)`. `benchmark_models(sensor)` gives the cost of each model for `bench`.

Two ground-truth models share one interface (`GroundTruthModel.bin_forces(contacts)` -> (rows, cols, 3) newtons,
compression positive, see tactile_msgs/msg/ForceDistribution.msg):

- "analytic" (default, ~0.05 ms per contact): Hertz (sphere) or Sneddon (flat punch) pressure on the compliant
  layer of elastic.compliant_layer, with the thin-layer stiffening of Dimitriadis et al. (2002) / Shull (2002),
  and the Cattaneo-Mindlin partial-slip traction of a sheared press. The axisymmetric traction is integrated
  exactly over rings of equal normal force, each ring split into angular sectors; the samples are binned with
  floor(), so the bin forces add up to the contact force to float precision and never divide 0 by 0.
  Several contacts superpose (each computed as if alone); samples off the surface are dropped.
- "numerical" (contact_solver.py): the same layer, solved on a fine surface grid for any height map and for the
  union of overlapping indenters (non-negative pressure by constrained conjugate gradients, FFT convolution).

docs/simulator-physics.md gives the formulas, references, validity limits and the calibration.
"""

from __future__ import annotations

import math
import time
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Protocol

import numpy as np

from tactile_description import BinGrid, SensorDescription
from tactile_description.value_checks import is_number, is_whole_number

from .elastic import CompliantLayer, compliant_layer

#: Deepest allowed press as a fraction of the compliant layer's thickness: beyond ~half the layer the strains
#: are far outside linear elasticity (and the thin-layer series below outside its fitted range).
MAX_DEPTH_LAYER_FRACTION = 0.5

#: Largest chi = sqrt(R d) / h of a sphere press: the edge of the Dimitriadis thin-layer series' fitted range (the
#: 10 mm sphere at the deepest press, 2 mm, has chi = 0.79). There it is within 7 % of the numerical model's exact
#: layer compliance (docs/simulator-physics.md); a 400 mm sphere 2 mm deep (chi = 5) is twice the exact force.
MAX_SPHERE_CHI = 0.8

#: Largest radius of a flat punch, in compliant-layer thicknesses (a / h): Shull's thin-layer form is within 4-8 %
#: of the numerical model for a / h <= 1, 20 % off at 1.25 and twice the exact force at 2.5.
MAX_PUNCH_RADIUS_LAYERS = 1.0

#: Largest Coulomb friction coefficient a contact may have (scenes and `tactile-sim press`): far above any gel's
#: (silicone on steel: about 1-3). From about 1e16 the stick depth's difference of two nearly equal depths rounded
#: to 0, and a sheared press reported no side force at all (found in review).
MAX_FRICTION = 10.0

#: Smallest radius at which the analytic model places its force samples. A vanishing contact (depth 1e-30 m) has
#: a radius below the rounding of its position; without this floor its samples would all round onto the centre,
#: and a centre exactly on a bin edge would load one side only instead of splitting evenly.
MIN_SAMPLE_RADIUS_M = 1e-12


def _positive(value: float, name: str) -> float:
    if not is_number(value) or value <= 0:
        raise ValueError(f"{name} must be a positive finite number of metres, got {value!r}")
    return float(value)


@dataclass(frozen=True)
class Sphere:
    """Rigid spherical indenter; the paper's indenter is 10 mm in diameter."""

    radius_m: float = 0.005

    def __post_init__(self):
        object.__setattr__(self, "radius_m", _positive(self.radius_m, "Sphere.radius_m"))


@dataclass(frozen=True)
class FlatPunch:
    """Rigid flat-ended cylinder pressed face down."""

    radius_m: float

    def __post_init__(self):
        object.__setattr__(self, "radius_m", _positive(self.radius_m, "FlatPunch.radius_m"))


@dataclass(frozen=True, eq=False)
class HeightMap:
    """Rigid indenter of any shape: `heights_m[i, j]` is its surface height above its lowest point (>= 0, min 0).

    Rows run along y, columns along x, `pixel_m` apart; the map is centred on the contact position (pixel (i, j)
    sits at x = (j - (W - 1) / 2) * pixel_m, y = (i - (H - 1) / 2) * pixel_m from it). Outside the map the
    indenter is absent. Only the "numerical" model takes height maps.
    """

    heights_m: np.ndarray
    pixel_m: float

    def __post_init__(self):
        heights = np.array(self.heights_m, dtype=np.float64)
        if heights.ndim != 2 or min(heights.shape) < 1:
            raise ValueError(f"HeightMap.heights_m must be a 2-D (H, W) array, got shape {heights.shape}")
        if not np.all(np.isfinite(heights)):
            raise ValueError("HeightMap.heights_m contains NaN or Inf; use finite heights in metres")
        if heights.min() != 0.0:
            raise ValueError(f"HeightMap.heights_m must be heights above the indenter's lowest point (minimum 0), "
                             f"got minimum {heights.min()!r} m: subtract heights_m.min()")
        heights.setflags(write=False)
        object.__setattr__(self, "heights_m", heights)
        object.__setattr__(self, "pixel_m", _positive(self.pixel_m, "HeightMap.pixel_m"))


Shape = Sphere | FlatPunch | HeightMap


@dataclass(frozen=True)
class Contact:
    """One indenter pressed `depth_m` into the surface at (x_m, y_m), then moved tangentially by `shear_m`."""

    x_m: float
    y_m: float
    depth_m: float
    shape: Shape = Sphere()
    shear_m: tuple[float, float] = (0.0, 0.0)
    friction: float = 1.0

    def __post_init__(self):
        for name in ("x_m", "y_m", "depth_m", "friction"):
            value = getattr(self, name)
            if not is_number(value):
                raise ValueError(f"Contact.{name} must be a finite number, got {value!r}")
            object.__setattr__(self, name, float(value))
        if self.depth_m < 0:
            raise ValueError(f"Contact.depth_m must be >= 0 (indentation into the surface, metres), got {self.depth_m}")
        if self.friction < 0:
            raise ValueError(f"Contact.friction must be >= 0 (Coulomb coefficient), got {self.friction}")
        if not isinstance(self.shape, (Sphere, FlatPunch, HeightMap)):
            raise ValueError(f"Contact.shape must be a Sphere, FlatPunch or HeightMap, got {type(self.shape).__name__}")
        shear = tuple(float(v) for v in np.asarray(self.shear_m, dtype=np.float64).ravel())
        if len(shear) != 2 or not all(math.isfinite(v) for v in shear):
            raise ValueError(f"Contact.shear_m must be two finite numbers (dx, dy) in metres, got {self.shear_m!r}")
        object.__setattr__(self, "shear_m", shear)


class GroundTruthModel(Protocol):
    """What the simulator calls to label a frame."""

    name: str
    #: Each contact computed alone and the bin forces added: contacts whose areas overlap are over-counted, and the
    #: simulator refuses scenes that may have them (Scene.check_playable).
    adds_contacts: bool

    def bin_forces(self, contacts: Sequence[Contact]) -> np.ndarray:
        """(rows, cols, 3) float64 bin forces in newtons, last axis (fx, fy, fz), fz > 0 in compression."""
        ...


def max_punch_radius_m(sensor: SensorDescription) -> float:
    """Widest flat punch the thin-layer punch formula holds for on this sensor (a / h <= MAX_PUNCH_RADIUS_LAYERS)."""
    return MAX_PUNCH_RADIUS_LAYERS * compliant_layer(sensor).thickness_m


def _depth_limits_m(sensor: SensorDescription, shape: Shape) -> dict[str, float]:
    """Each limit on the depth of a press with `shape`, by the reason for it."""
    h = compliant_layer(sensor).thickness_m
    limits = {"half the compliant gel": MAX_DEPTH_LAYER_FRACTION * h}
    if isinstance(shape, Sphere):
        limits["the sphere's radius"] = shape.radius_m
        limits[f"chi = sqrt(R d) / h at most {MAX_SPHERE_CHI}, the range of the thin-layer sphere formula "
               f"(Dimitriadis)"] = (MAX_SPHERE_CHI * h) ** 2 / shape.radius_m
    elif isinstance(shape, HeightMap):
        limits["the height map's tallest point"] = float(shape.heights_m.max())
    return limits


def max_depth_m(sensor: SensorDescription, shape: Shape) -> float:
    """Deepest allowed press for `shape` on this sensor; deeper presses raise ValueError (they are not clamped).

    Half the compliant layer (2 mm on the reference sensor), no deeper than the indenter itself is tall (a sphere's
    radius, a height map's tallest point), and for a sphere no deeper than chi = sqrt(R d) / h = MAX_SPHERE_CHI.
    """
    return min(_depth_limits_m(sensor, shape).values())


def press_problem(sensor: SensorDescription, shape: Shape, depth_m: float) -> str | None:
    """Why pressing `shape` `depth_m` deep on this sensor is outside the contact models' range, or None if it is not.

    A flat punch wider than max_punch_radius_m, or a depth beyond max_depth_m (the message names the limit).
    """
    name = sensor.name
    if isinstance(shape, FlatPunch) and shape.radius_m > max_punch_radius_m(sensor):
        h = compliant_layer(sensor).thickness_m
        return (f"a flat punch {shape.radius_m * 2e3:.4g} mm in diameter on the {h * 1e3:.4g} mm compliant gel of "
                f"sensor {name!r} has a / h = {shape.radius_m / h:.3g}, above {MAX_PUNCH_RADIUS_LAYERS:g}, where the "
                f"thin-layer punch formula (Shull) holds; use a punch at most {max_punch_radius_m(sensor) * 2e3:.4g} "
                f"mm in diameter")
    limits = _depth_limits_m(sensor, shape)
    reason = min(limits, key=limits.get)
    if depth_m > limits[reason]:
        return (f"a press {depth_m * 1e3:.4g} mm deep is deeper than the deepest allowed press of "
                f"{limits[reason] * 1e3:.4g} mm for {shape} on sensor {name!r} ({reason}); press less deep")
    return None


def shear_problem(sensor: SensorDescription, shear_m: float) -> str | None:
    """Why a shear of `shear_m` (its length) is outside the contact models' range, or None if it is not: one longer
    than the compliant gel is thick."""
    max_shear_m = compliant_layer(sensor).thickness_m
    if shear_m <= max_shear_m:
        return None
    return (f"a shear of {shear_m * 1e3:.4g} mm is longer than the {max_shear_m * 1e3:.4g} mm compliant gel of sensor "
            f"{sensor.name!r} is thick; the contact models keep the contact where it was pressed, which holds for a "
            f"shear short against the gel: shear at most {max_shear_m * 1e3:.4g} mm")


def check_contact(sensor: SensorDescription, contact: Contact) -> None:
    """Raise ValueError if the contact is outside the contact models' range (see press_problem)."""
    problem = press_problem(sensor, contact.shape, contact.depth_m)
    if problem is not None:
        raise ValueError(f"Contact: {problem}")


# --- axisymmetric contact of a rigid indenter on the bonded layer ------------------------------------------------

def dimitriadis_factor(chi: float) -> float:
    """Force of a sphere on a bonded incompressible layer over the Hertz force, chi = sqrt(R d) / h.

    Dimitriadis, Horkay, Maresca, Kachar, Chadwick, Biophys. J. 82 (2002) 2798, eq. for a layer bonded to a rigid
    substrate with nu = 0.5 (the gel's nu = 0.49 is taken as incompressible here):
    F = F_Hertz [1 + 1.133 chi + 1.283 chi^2 + 0.769 chi^3 + 0.0975 chi^4]; -> 1 as h -> infinity.
    """
    return 1.0 + chi * (1.133 + chi * (1.283 + chi * (0.769 + chi * 0.0975)))


def shull_punch_factor(ratio: float) -> float:
    """Stiffness of a flat punch of radius a on a bonded incompressible layer over Sneddon's, ratio = a / h.

    The form of Shull, Mater. Sci. Eng. R 36 (2002) 1, for a layer bonded to a rigid substrate:
    P = 2 E* a d [1 + 1.33 (a/h) + beta (a/h)^3], beta between 0.33 and 1.33 with the friction on the punch face.
    beta = 1.33 matches the exact layer compliance of the numerical model within ~7 % for a/h <= 1 (tested in
    test_contact_solver.py); -> 1 as h -> infinity.
    """
    return 1.0 + 1.33 * ratio + 1.33 * ratio**3


@dataclass(frozen=True)
class AxisymmetricLoad:
    """Normal load of one axisymmetric contact: total force, contact radius, and the shape of its pressure."""

    force_n: float
    radius_m: float
    kind: str  # "hertz": p ~ sqrt(1 - r^2/a^2); "punch": p ~ 1 / sqrt(1 - r^2/a^2)

    def cumulative_fraction(self, r_m: np.ndarray) -> np.ndarray:
        """Fraction of the force inside radius r (Johnson 1985 eqs. 4.22 (Hertz) and 3.35 (punch)), clipped."""
        if self.radius_m <= 0.0:
            return np.ones_like(r_m)
        s = 1.0 - np.minimum(np.asarray(r_m) / self.radius_m, 1.0) ** 2
        return 1.0 - s**1.5 if self.kind == "hertz" else 1.0 - np.sqrt(s)

    def radius_of_fraction(self, u: np.ndarray) -> np.ndarray:
        """Inverse of cumulative_fraction: the radius inside which a fraction u of the force acts."""
        u = np.clip(u, 0.0, 1.0)
        if self.kind == "hertz":
            return self.radius_m * np.sqrt(1.0 - (1.0 - u) ** (2.0 / 3.0))
        return self.radius_m * np.sqrt(u * (2.0 - u))


def contact_radius_m(shape: Shape, depth_m: float) -> float:
    """Radius of the contact of `shape` pressed `depth_m` deep: Hertz's a = sqrt(R d) for a sphere, the punch's own,
    and for a height map the farthest reach of its pixels within `depth_m` of its lowest point (each pixel's centre
    plus half its diagonal): the footprint of a rigid indentation, which the contact does not exceed (the surface
    sinks around an indenter: a sphere's footprint sqrt(2 R d - d^2) is 1.4 times Hertz's radius)."""
    if isinstance(shape, Sphere):
        return math.sqrt(shape.radius_m * depth_m)
    if isinstance(shape, HeightMap):
        rows, cols = np.nonzero(shape.heights_m <= depth_m)
        height, width = shape.heights_m.shape
        centre_px = np.hypot(cols - (width - 1) / 2, rows - (height - 1) / 2).max()
        return float(centre_px + math.sqrt(0.5)) * shape.pixel_m
    return shape.radius_m


def reach_problem(grid: BinGrid, x_m: float, y_m: float, shape: Shape, depth_m: float) -> str | None:
    """Why a contact centred at (x_m, y_m) presses nothing on `grid`'s surface at `depth_m`: its centre lies beside the
    surface by at least the radius its contact reaches (None where it touches). Scenes and `tactile-sim press` refuse
    such a contact: it gives no force, and a user who typed millimetres of another sensor got 0 N without a word."""
    off_x = max(-x_m, 0.0, x_m - grid.width_m)
    off_y = max(-y_m, 0.0, y_m - grid.length_m)
    off, reach = math.hypot(off_x, off_y), contact_radius_m(shape, depth_m)
    if off > 0 and off >= reach:
        return (f"a press at ({x_m * 1e3:g}, {y_m * 1e3:g}) mm is {off * 1e3:.3g} mm off the {grid.width_m * 1e3:g} "
                f"x {grid.length_m * 1e3:g} mm surface, beyond the {reach * 1e3:.3g} mm its contact reaches at its "
                "deepest: it would press nothing")
    return None


def normal_load(layer: CompliantLayer, shape: Sphere | FlatPunch, depth_m: float) -> AxisymmetricLoad:
    """Hertz / Sneddon normal load on the layer, stiffened for its finite thickness.

    Sphere (Hertz, Johnson eq. 4.23): a = sqrt(R d), F = (4/3) E* sqrt(R) d^(3/2) * dimitriadis_factor(a / h).
    Flat punch (Sneddon 1965, Johnson eq. 3.36): a = punch radius, F = 2 E* a d * shull_punch_factor(a / h).
    """
    e_star = layer.plane_strain_modulus_pa
    h = layer.thickness_m
    if isinstance(shape, Sphere):
        a = contact_radius_m(shape, depth_m)
        force = 4.0 / 3.0 * e_star * math.sqrt(shape.radius_m) * depth_m**1.5 * dimitriadis_factor(a / h)
        return AxisymmetricLoad(force, a, "hertz")
    if isinstance(shape, FlatPunch):
        a = contact_radius_m(shape, depth_m)
        return AxisymmetricLoad(2.0 * e_star * a * depth_m * shull_punch_factor(a / h), a, "punch")
    raise ValueError(f"the analytic model takes Sphere and FlatPunch indenters, got {type(shape).__name__}: "
                     f"use ground_truth_model(sensor, 'numerical') for height maps")


def stick_depth_m(layer: CompliantLayer, contact: Contact) -> float:
    """Depth d' whose contact area is the stick zone of the sheared contact (0: the whole contact slides).

    Cattaneo-Mindlin in the form of Jaeger / Ciavarella (Ciavarella, Int. J. Solids Struct. 35 (1998) 2349):
    the partial-slip traction is q = mu [p(d) - p(d')] with d - d' = 2 (1 - nu) |shear| / (mu (2 - nu)). For a
    Hertz sphere this is Mindlin's c = a sqrt(1 - delta / delta_slip) (Johnson eqs. 7.39-7.42); for a flat punch it
    is Mindlin's stick stiffness 8 G a / (2 - nu) up to gross slip.
    """
    shear = math.hypot(*contact.shear_m)
    if contact.friction == 0.0 or shear == 0.0:
        return contact.depth_m
    nu = layer.poisson_ratio
    return max(0.0, contact.depth_m - 2.0 * (1.0 - nu) * shear / (contact.friction * (2.0 - nu)))


class AnalyticContactModel:
    """Closed-form axisymmetric contacts sampled on rings x sectors and binned (see the module docstring).

    `rings` rings of equal normal force, each split into `sectors` equal angular sectors (a multiple of 4, offset
    by half a sector, so a sample set centred on a bin corner splits evenly between the four bins and mirrors
    onto itself about x and y). 24 x 32 samples resolve a contact of radius a to ~a / 24 radially.
    """

    name = "analytic"
    adds_contacts = True

    def __init__(self, sensor: SensorDescription, rings: int = 24, sectors: int = 32):
        if not (is_whole_number(rings) and is_whole_number(sectors, 4) and sectors % 4 == 0):
            raise ValueError(f"rings must be a whole number >= 1 and sectors a positive multiple of 4, got {rings!r}, "
                             f"{sectors!r}")
        self.sensor = sensor
        self.layer = compliant_layer(sensor)
        self._rings = rings
        self._sectors = sectors
        self._ring_edges = np.linspace(0.0, 1.0, rings + 1)           # cumulative force fractions
        self._ring_mids = (np.arange(rings) + 0.5) / rings
        angles = (np.arange(sectors) + 0.5) * (2.0 * math.pi / sectors)
        self._cos = np.cos(angles)
        self._sin = np.sin(angles)

    def bin_forces(self, contacts: Sequence[Contact]) -> np.ndarray:
        grid = self.sensor.grid
        out = np.zeros(grid.n_bins * 3)
        for contact in contacts:
            if not isinstance(contact, Contact):
                raise ValueError(f"contacts must hold Contact objects, got {type(contact).__name__}")
            check_contact(self.sensor, contact)
            if contact.depth_m > 0.0:
                self._add_contact(contact, out)
        return out.reshape(grid.rows, grid.cols, 3)

    def _add_contact(self, contact: Contact, out: np.ndarray) -> None:
        grid = self.sensor.grid
        normal = normal_load(self.layer, contact.shape, contact.depth_m)
        radii = np.maximum(normal.radius_of_fraction(self._ring_mids), MIN_SAMPLE_RADIUS_M)
        ring_normal = np.full(self._rings, normal.force_n / self._rings)

        stick = normal_load(self.layer, contact.shape, stick_depth_m(self.layer, contact))
        edges = normal.radius_of_fraction(self._ring_edges)
        edges[-1] = max(normal.radius_m, stick.radius_m) * 2.0 + 1.0  # everything inside the last ring
        cumulative_q = contact.friction * (normal.force_n * normal.cumulative_fraction(edges)
                                           - stick.force_n * stick.cumulative_fraction(edges))
        cumulative_q[0] = 0.0
        ring_tangential = np.diff(cumulative_q)
        shear = math.hypot(*contact.shear_m)
        direction = np.array(contact.shear_m) / shear if shear > 0 else np.zeros(2)

        x = contact.x_m + radii[:, None] * self._cos[None, :]
        y = contact.y_m + radii[:, None] * self._sin[None, :]
        col = np.floor(x / grid.bin_width_m)
        row = np.floor(y / grid.bin_length_m)
        on_surface = (col >= 0) & (col < grid.cols) & (row >= 0) & (row < grid.rows)
        if not on_surface.any():
            return
        flat = (row * grid.cols + col)[on_surface].astype(np.int64)
        per_sector = 1.0 / self._sectors
        fz = np.broadcast_to(ring_normal[:, None] * per_sector, x.shape)[on_surface]
        ft = np.broadcast_to(ring_tangential[:, None] * per_sector, x.shape)[on_surface]
        size = grid.n_bins
        out[2::3] += np.bincount(flat, weights=fz, minlength=size)
        if direction.any():
            out[0::3] += np.bincount(flat, weights=ft * direction[0], minlength=size)
            out[1::3] += np.bincount(flat, weights=ft * direction[1], minlength=size)


#: The ground-truth models by name; the first is the default (Simulator's and the commands').
GROUND_TRUTH_MODELS = ("analytic", "numerical")


def ground_truth_model(sensor: SensorDescription, name: str = GROUND_TRUTH_MODELS[0]) -> GroundTruthModel:
    """The ground-truth model called `name`: "analytic" (default, fast) or "numerical" (any height map)."""
    if name == "analytic":
        return AnalyticContactModel(sensor)
    if name == "numerical":
        from .contact_solver import NumericalContactModel

        return NumericalContactModel(sensor)
    raise ValueError(f"unknown ground-truth model {name!r}; choose 'analytic' or 'numerical'")


# --- the `press` command and the benchmark --------------------------------------------------------------------------

def press_contact(x_mm: float, y_mm: float, depth_mm: float, shape: str = "sphere", radius_mm: float | None = None,
                  shear_x_mm: float = 0.0, shear_y_mm: float = 0.0, friction: float = 1.0) -> Contact:
    """The contact described by the `tactile-sim press` options (millimetres, as typed on the command line). A value
    refused is named by its option, in millimetres: Contact's own refusal named its field, in metres."""
    for option, value, low in (("--x-mm", x_mm, -math.inf), ("--y-mm", y_mm, -math.inf), ("--depth-mm", depth_mm, 0.0),
                               ("--shear-x-mm", shear_x_mm, -math.inf), ("--shear-y-mm", shear_y_mm, -math.inf),
                               ("--radius-mm", 1.0 if radius_mm is None else radius_mm, 1e-9)):
        if not (is_number(value) and value >= low):
            bound = "" if low == -math.inf else " > 0" if low > 0 else " >= 0"
            raise ValueError(f"{option} must be a finite number of millimetres{bound}, got {value!r}")
    if not (is_number(friction) and 0.0 <= friction <= MAX_FRICTION):
        raise ValueError(f"--friction must be a Coulomb coefficient from 0 to {MAX_FRICTION:g}, as in scenes, got "
                         f"{friction!r}")
    if shape == "sphere":
        indenter: Shape = Sphere() if radius_mm is None else Sphere(radius_mm * 1e-3)
    elif shape == "punch":
        if radius_mm is None:
            raise ValueError("--shape punch needs --radius-mm (the punch radius in millimetres)")
        indenter = FlatPunch(radius_mm * 1e-3)
    else:
        raise ValueError(f"--shape must be 'sphere' or 'punch', got {shape!r}")
    return Contact(x_mm * 1e-3, y_mm * 1e-3, depth_mm * 1e-3, indenter, (shear_x_mm * 1e-3, shear_y_mm * 1e-3),
                   friction)


def contact_record(contact: Contact) -> dict:
    """A contact as `tactile-sim press --json` and a data set's contacts.json write it, in millimetres as scenes give
    it. Rounded to the picometre (1e-9 mm): a scene's 25.5 mm, held in metres, came back as 25.500000000000004."""
    def mm(value_m: float) -> float:
        return round(value_m * 1e3, 9)

    shape = contact.shape
    return {"x_mm": mm(contact.x_m), "y_mm": mm(contact.y_m), "depth_mm": mm(contact.depth_m),
            "shape": type(shape).__name__,
            "radius_mm": mm(shape.radius_m) if isinstance(shape, (Sphere, FlatPunch)) else None,
            "shear_mm": [mm(v) for v in contact.shear_m], "friction": contact.friction}


def press_report(sensor: SensorDescription, contact: Contact, model: GroundTruthModel) -> dict:
    """The JSON object `tactile-sim press --json` prints: the bin forces of one contact and their total. A shear or a
    place the scenes refuse (shear_problem, reach_problem) is refused here too (ValueError)."""
    problem = shear_problem(sensor, float(np.hypot(*contact.shear_m)))
    if problem is not None:
        raise ValueError(f"Contact: {problem}")
    problem = reach_problem(sensor.grid, contact.x_m, contact.y_m, contact.shape, contact.depth_m)
    if problem is not None:
        raise ValueError(f"{problem} (--x-mm and --y-mm are millimetres from the surface's corner)")
    forces = model.bin_forces([contact])
    return {
        "sensor": sensor.name,
        "model": model.name,
        "contact": contact_record(contact),
        "rows": sensor.grid.rows,
        "cols": sensor.grid.cols,
        "total_force_n": forces.sum(axis=(0, 1)).tolist(),
        "loaded_bins": int(np.count_nonzero(np.any(forces != 0.0, axis=2))),
        "bin_forces_n": forces.reshape(-1, 3).tolist(),
    }


def reference_press(sensor: SensorDescription) -> Contact:
    """The paper's calibration press: the 10 mm sphere 1.5 mm deep at the centre of the surface."""
    return Contact(*sensor.grid.centre_m, 1.5e-3, Sphere(0.005))


def benchmark_models(sensor: SensorDescription, repeats: int = 21, numerical_repeats: int = 5) -> dict:
    """Median cost (ms per frame) of each ground-truth model on the reference press and on a sheared press.

    Each model reports its median over `repeats` runs (the numerical model's over `numerical_repeats`; after a warm-up
    that fills caches), the total force it found, and its cost relative to the analytic model measured in the same run.
    """
    press = reference_press(sensor)
    sheared = Contact(press.x_m, press.y_m, press.depth_m, press.shape, shear_m=(2e-4, 1e-4), friction=0.8)
    result = {}
    for name, runs in (("analytic", repeats), ("numerical", numerical_repeats)):
        model = ground_truth_model(sensor, name)
        entry = {"runs": runs}
        for label, contact in (("press", press), ("sheared_press", sheared)):
            model.bin_forces([contact])  # warm-up (kernel caches)
            times = []
            for _ in range(runs):
                start = time.perf_counter()
                forces = model.bin_forces([contact])
                times.append(time.perf_counter() - start)
            entry[f"{label}_ms_median"] = 1e3 * float(np.median(times))
            entry[f"{label}_total_force_n"] = forces.sum(axis=(0, 1)).tolist()
        result[name] = entry
    for name in result:
        result[name]["cost_vs_analytic"] = result[name]["press_ms_median"] / result["analytic"]["press_ms_median"]
    return result
