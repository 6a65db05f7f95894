"""Scenes: a YAML timeline of contacts plus the effects to apply (format in docs/simulator.md).

A scene is a list of timeline segments, each a one-key mapping that expands into frames:
  rest            frames without contact
  press           one indenter at a fixed place, one frame per listed depth
  contacts        one frame with several explicit contacts (repeated `repeat` times)
  press_grid      vertical presses on a regular grid of positions, several depths each (the paper's data set)
  random_presses  frames of 1..k simultaneous presses at random places/depths/shears, anywhere or at edges/corners
  path            one press sliding along waypoints (the live demo)
Frames are generated lazily and reproducibly: segment i draws from the random stream seeded (seed, 0, i), so
the same file always gives the same contacts, and a shortened scene gives a prefix of the full one.

A place on the surface is given in millimetres from its corner (`x_mm`, `waypoints_mm`) or in fractions of its width
and length (`x_fraction`, `waypoints_fraction`: a Place), which fit any sensor's surface; the sensor's grid turns
them into metres when frames are made or checked.
"""

from __future__ import annotations

import itertools
import math
import os
import re
from collections.abc import Iterator
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from tactile_description import BinGrid, SensorConfigError, SensorDescription, installed_config_dir
from tactile_description.value_checks import is_number, is_whole_number
from tactile_description.yaml_fields import YamlFields, load_yaml_file
from tactile_sim.contact import (
    MAX_FRICTION,
    Contact,
    FlatPunch,
    GroundTruthModel,
    Shape,
    Sphere,
    contact_radius_m,
    press_problem,
    reach_problem,
    shear_problem,
)
from tactile_sim.effects import MAX_EFFECT_FRAME, EffectContext, EffectSpec, SceneError, parse_effect

MM = 1e-3
SEGMENT_KINDS = ("rest", "press", "contacts", "press_grid", "random_presses", "path")
REGIONS = ("surface", "edges", "corners")

#: What a scene's name may be: previews and progress bars are named after it, so a safe file name.
SCENE_NAME = re.compile(r"[A-Za-z0-9_-][A-Za-z0-9_.-]{0,99}")

#: Most frames a scene may have (all segments together): 10 million frames of the reference sensor are 640 GB.
MAX_FRAMES = MAX_EFFECT_FRAME

#: Largest distance a random press's min_separation_mm or edge_band_mm may name, mm (1 m, 20 reference surfaces): 1e199
#: mm overflowed a float in the check that the contacts fit (found in review).
MAX_SCENE_LENGTH_MM = 1000.0

#: Largest indenter diameter a scene may name, mm (twice the reference surface); the sensor's gel then limits the
#: sphere's depth and the punch's diameter further (contact.press_problem).
MAX_DIAMETER_MM = 100.0

#: random_presses draws a frame's centres by rejection: this many tries per contact before it gives up (SceneError).
TRIES_PER_CONTACT = 64


def _fields(node, where: str) -> YamlFields:
    return YamlFields(node, where, SceneError)


def _indenter(node, where: str) -> Shape:
    n = _fields(node, where)
    kind = n.raw("shape", required=True)
    if kind == "sphere":
        shape: Shape = Sphere(0.5 * n.number("diameter_mm", low=0.1, high=MAX_DIAMETER_MM) * MM)
    elif kind == "flat_punch":
        shape = FlatPunch(0.5 * n.number("diameter_mm", low=0.1, high=MAX_DIAMETER_MM) * MM)
    else:
        raise SceneError(f"{where}.shape must be 'sphere' or 'flat_punch', got {kind!r}")
    n.finish()
    return shape


# --- segments -------------------------------------------------------------------------------------------------------

@dataclass(frozen=True)
class Extremes:
    """The deepest press and the longest shear of one indenter in a segment (`where`: its key path), which
    Scene.validate checks against the sensor."""

    where: str
    shape: Shape
    depth_m: float
    shear_m: float


@dataclass(frozen=True)
class Place:
    """A point of the surface as a scene gives it: metres from the surface's corner, or fractions of its width (x) and
    length (y)."""

    x: float
    y: float
    fraction: bool

    def metres(self, grid: BinGrid) -> tuple[float, float]:
        return (self.x * grid.width_m, self.y * grid.length_m) if self.fraction else (self.x, self.y)


@dataclass(frozen=True)
class Segment:
    """One timeline entry: `kind`, its parameters (SI), its frame count and its presses' extremes."""

    kind: str
    params: dict
    n_frames: int
    extremes: tuple[Extremes, ...]
    where: str

    def frames(self, rng: np.random.Generator, grid) -> Iterator[tuple[Contact, ...]]:
        return _GENERATORS[self.kind](self.params, rng, grid, self.n_frames)


def _contact(node, where: str, default_shape: Shape) -> tuple[Place, Contact]:
    """A contact of a `contacts` segment: its place, and the contact at the surface's corner (`_placed`)."""
    n = _fields(node, where)
    shape = _indenter(n.raw("indenter"), f"{where}.indenter") if n.has("indenter") else default_shape
    place = _place(n)
    depth = n.number("depth_mm", low=0.0) * MM
    shear = tuple(v * MM for v in n.numbers("shear_mm", 2, [0.0, 0.0]))
    friction = n.number("friction", 1.0, low=0.0, high=MAX_FRICTION)
    n.finish()
    return place, Contact(0.0, 0.0, depth, shape, shear, friction)


def _placed(contacts, grid: BinGrid) -> tuple[Contact, ...]:
    """The contacts of a `contacts` segment ((place, contact) pairs) at their places on `grid`'s surface."""
    return tuple(replace(contact, x_m=x, y_m=y) for place, contact in contacts for x, y in [place.metres(grid)])


def _place(n: YamlFields) -> Place:
    """x_mm and y_mm, or x_fraction and y_fraction of the surface's width and length."""
    mm, fraction = n.has("x_mm") or n.has("y_mm"), n.has("x_fraction") or n.has("y_fraction")
    if mm == fraction:
        raise SceneError(f"{n.where}: " + ("give x_mm and y_mm, or x_fraction and y_fraction, not a mix of the two"
                                           if mm else "missing its place: x_mm and y_mm, or x_fraction and y_fraction"))
    x, y = ("x_fraction", "y_fraction") if fraction else ("x_mm", "y_mm")
    if not (n.has(x) and n.has(y)):  # with y alone, the typo hint named it for a missing x (review)
        raise SceneError(f"{n.where}: give both {x} and {y}")
    if fraction:
        return Place(n.number(x), n.number(y), fraction=True)
    return Place(n.number(x) * MM, n.number(y) * MM, fraction=False)


def _contacts_per_frame(n: YamlFields) -> tuple[int, int]:
    given = n.raw("contacts_per_frame", 1)
    per_frame = [given, given] if is_whole_number(given) else given
    if not (isinstance(per_frame, list) and len(per_frame) == 2 and all(is_whole_number(v) for v in per_frame)
            and per_frame[0] <= per_frame[1] <= 16):
        raise SceneError(f"{n.where}.contacts_per_frame must be an integer or [min, max] with 1 <= min <= max <= 16, "
                         f"got {given!r}")
    return per_frame[0], per_frame[1]


def _waypoints(n: YamlFields) -> tuple[Place, ...]:
    """waypoints_mm, or waypoints_fraction of the surface's width and length."""
    fraction = n.has("waypoints_fraction")
    if fraction == n.has("waypoints_mm"):
        raise SceneError(f"{n.where}: " + ("give waypoints_mm or waypoints_fraction, not both" if fraction
                                           else "missing its waypoints: waypoints_mm or waypoints_fraction"))
    key, unit, scale = ("waypoints_fraction", "fractions", 1.0) if fraction else ("waypoints_mm", "mm", MM)
    waypoints = n.raw(key, required=True)
    if not (isinstance(waypoints, list) and len(waypoints) >= 2 and all(
            isinstance(w, list) and len(w) == 2 and all(is_number(v) for v in w) for w in waypoints)):
        raise SceneError(f"{n.where}.{key} must list at least two [x, y] points (finite numbers, {unit}), "
                         f"got {waypoints!r}")
    return tuple(Place(x * scale, y * scale, fraction) for x, y in waypoints)


def _parse_segment(entry, where: str, default_shape: Shape) -> Segment:
    if not (isinstance(entry, dict) and len(entry) == 1):
        raise SceneError(f"{where} must be a one-key mapping naming the segment kind {SEGMENT_KINDS}, got {entry!r}")
    (kind, body), = entry.items()
    if kind not in SEGMENT_KINDS:
        raise SceneError(f"{where}: unknown segment kind {kind!r}; known kinds are {list(SEGMENT_KINDS)}")
    where = f"{where}.{kind}"
    n = _fields(body, where)
    shape = _indenter(n.raw("indenter"), f"{where}.indenter") if n.has("indenter") else default_shape
    params: dict = {"shape": shape, "where": where}
    if kind == "rest":
        count, deepest, shear = n.count("frames"), 0.0, 0.0  # presses nothing: no extremes (below)
    elif kind == "press":
        depths = n.raw("depths_mm", required=True)
        if not (isinstance(depths, list) and depths and all(is_number(d) and d >= 0 for d in depths)):
            raise SceneError(f"{where}.depths_mm must be a non-empty list of depths >= 0 (mm), got {depths!r}")
        params.update(place=_place(n), depths_m=tuple(d * MM for d in depths),
                      shear_m=tuple(v * MM for v in n.numbers("shear_mm", 2, [0.0, 0.0])),
                      friction=n.number("friction", 1.0, low=0.0, high=MAX_FRICTION))
        count, deepest, shear = len(depths), max(depths) * MM, math.hypot(*params["shear_m"])
    elif kind == "contacts":
        items = n.raw("contacts", required=True)
        if not (isinstance(items, list) and items):
            raise SceneError(f"{where}.contacts must be a non-empty list of contacts, got {items!r}")
        wheres = [f"{where}.contacts[{i}]" for i in range(len(items))]
        params["contacts"] = tuple(_contact(c, w, shape) for c, w in zip(items, wheres, strict=True))
        count = n.count("repeat", 1)
        n.finish()
        return Segment(kind, params, count, tuple(Extremes(w, c.shape, c.depth_m, math.hypot(*c.shear_m))
                                                  for (_, c), w in zip(params["contacts"], wheres, strict=True)), where)
    elif kind == "press_grid":
        params.update(cols=n.count("cols"), rows=n.count("rows"), margin_m=n.number("margin_mm", 0.0, low=0.0) * MM,
                      jitter_m=n.number("jitter_mm", 0.0, low=0.0) * MM,
                      depth_m=tuple(v * MM for v in n.span("depth_mm")),
                      per_position=n.count("depths_per_position"),
                      shear_m=tuple(v * MM for v in n.span("shear_mm")) if n.has("shear_mm") else None,
                      friction=n.number("friction", 1.0, low=0.0, high=MAX_FRICTION))
        count = params["cols"] * params["rows"] * params["per_position"]
        deepest, shear = params["depth_m"][1], params["shear_m"][1] if params["shear_m"] else 0.0
    elif kind == "random_presses":
        region = n.raw("region", "surface")
        if region not in REGIONS:
            raise SceneError(f"{where}.region must be one of {list(REGIONS)}, got {region!r}")
        # Each region places its centres by one of the two keys; the other was ignored without a word (review).
        unused = "edge_band_mm" if region == "surface" else "margin_mm"
        if n.has(unused):
            raise SceneError(f"{where}.{unused} does not apply to region {region!r}: centres "
                             + ("on the surface keep margin_mm from its edges" if region == "surface" else
                                "near an edge or corner lie at a distance from it within edge_band_mm")
                             + f"; remove {unused}")
        params.update(region=region, contacts_per_frame=_contacts_per_frame(n),
                      depth_m=tuple(v * MM for v in n.span("depth_mm")),
                      shear_m=tuple(v * MM for v in n.span("shear_mm", [0.0, 0.0])),
                      margin_m=n.number("margin_mm", 0.0, low=0.0) * MM,
                      edge_band_m=tuple(v * MM for v in n.numbers("edge_band_mm", 2, [-2.0, 3.0])),
                      min_separation_m=n.number("min_separation_mm", 0.0, low=0.0, high=MAX_SCENE_LENGTH_MM) * MM,
                      friction=n.number("friction", 1.0, low=0.0, high=MAX_FRICTION))
        inner, outer = params["edge_band_m"]
        if not (-MAX_SCENE_LENGTH_MM * MM <= inner <= outer <= MAX_SCENE_LENGTH_MM * MM):
            raise SceneError(f"{where}.edge_band_mm must be [inner, outer] signed distances with inner <= outer, "
                             f"within +-{MAX_SCENE_LENGTH_MM:g} mm")
        count, deepest, shear = n.count("frames"), params["depth_m"][1], params["shear_m"][1]
    else:  # path
        count = n.count("frames", low=2)
        params.update(waypoints=_waypoints(n),
                      depth_m=n.number("depth_mm", low=0) * MM,
                      ramp_frames=n.count("ramp_frames", 0, low=0),
                      shear_m=tuple(v * MM for v in n.numbers("shear_mm", 2, [0.0, 0.0])))
        if 2 * params["ramp_frames"] > count:
            raise SceneError(f"{where}.ramp_frames ({params['ramp_frames']}) must be at most half of frames ({count})")
        deepest, shear = params["depth_m"], math.hypot(*params["shear_m"])
    n.finish()
    return Segment(kind, params, count, () if kind == "rest" else (Extremes(where, shape, deepest, shear),), where)


def _rest(p, rng, grid, n):
    for _ in range(n):
        yield ()


def _press(p, rng, grid, n):
    for depth in p["depths_m"]:
        yield (Contact(*p["place"].metres(grid), depth, p["shape"], p["shear_m"], p["friction"]),)


def _contacts(p, rng, grid, n):
    contacts = _placed(p["contacts"], grid)
    for _ in range(n):
        yield contacts


def _press_grid(p, rng, grid, n):
    """Grid positions (cell centres of a cols x rows grid inside the margin), each pressed at `per_position` depths:
    evenly spread over the depth range with a random offset of up to half a step, and a uniform position jitter.
    With a shear range, each press is then sheared by a magnitude uniform in it, in a uniformly random direction,
    drawn from a generator spawned from `rng` (which leaves `rng`'s own draws as they are): the sheared grid presses
    the same places to the same depths as the grid without shear, which draws what it drew before shear existed."""
    shear_rng = rng.spawn(1)[0] if p["shear_m"] is not None else None
    low, high = p["depth_m"]
    k = p["per_position"]
    step = (high - low) / k
    xs = p["margin_m"] + (np.arange(p["cols"]) + 0.5) * (grid.width_m - 2 * p["margin_m"]) / p["cols"]
    ys = p["margin_m"] + (np.arange(p["rows"]) + 0.5) * (grid.length_m - 2 * p["margin_m"]) / p["rows"]
    for y in ys:
        for x in xs:
            depths = low + (np.arange(k) + rng.uniform(0.0, 1.0, k)) * step
            jitter = rng.uniform(-p["jitter_m"], p["jitter_m"], (k, 2))
            magnitudes, angles = np.zeros(k), np.zeros(k)
            if shear_rng is not None:
                magnitudes, angles = shear_rng.uniform(*p["shear_m"], k), shear_rng.uniform(0.0, 2.0 * math.pi, k)
            for depth, (jx, jy), magnitude, angle in zip(depths, jitter, magnitudes, angles, strict=True):
                yield (Contact(float(x + jx), float(y + jy), float(min(depth, high)), p["shape"],
                               _shear(float(magnitude), float(angle)), p["friction"]),)


def _shear(magnitude: float, angle: float) -> tuple[float, float]:
    """The tangential displacement (x, y) of `magnitude` metres in direction `angle` (radians from +x)."""
    return magnitude * math.cos(angle), magnitude * math.sin(angle)


def _edge_point(region: str, band: tuple[float, float], rng, grid) -> tuple[float, float]:
    """A point whose distance inside the nearest edge (negative: outside) is uniform in `band`, on a random edge
    (region "edges") or near a random corner (region "corners", both coordinates in the band)."""
    width, length = grid.width_m, grid.length_m
    inward = rng.uniform(*band, 2)
    if region == "corners":
        corner = rng.integers(0, 2, 2)
        return (float(inward[0] if corner[0] == 0 else width - inward[0]),
                float(inward[1] if corner[1] == 0 else length - inward[1]))
    edge = int(rng.integers(0, 4))
    if edge < 2:  # x = 0 or x = width
        return float(inward[0] if edge == 0 else width - inward[0]), float(rng.uniform(0.0, length))
    return float(rng.uniform(0.0, width)), float(inward[1] if edge == 2 else length - inward[1])


def _random_presses(p, rng, grid, n):
    """Frames of k contacts (k uniform in contacts_per_frame): centres drawn one by one, a centre closer than
    min_separation to one already placed is drawn again; after TRIES_PER_CONTACT * k draws without k centres the
    scene is refused (SceneError) rather than given fewer contacts than it asks for."""
    low, high = p["contacts_per_frame"]
    margin = p["margin_m"]
    for frame in range(n):
        k = int(rng.integers(low, high + 1))
        contacts: list[Contact] = []
        for _ in range(TRIES_PER_CONTACT * k):
            if len(contacts) == k:
                break
            if p["region"] == "surface":
                x = float(rng.uniform(margin, grid.width_m - margin))
                y = float(rng.uniform(margin, grid.length_m - margin))
            else:
                x, y = _edge_point(p["region"], p["edge_band_m"], rng, grid)
            if any(math.hypot(x - c.x_m, y - c.y_m) < p["min_separation_m"] for c in contacts):
                continue
            magnitude = float(rng.uniform(*p["shear_m"]))
            angle = float(rng.uniform(0.0, 2.0 * math.pi))
            contacts.append(Contact(x, y, float(rng.uniform(*p["depth_m"])), p["shape"], _shear(magnitude, angle),
                                    p["friction"]))
        if len(contacts) < k:
            raise SceneError(f"{p['where']}: frame {frame} of the segment found room for only {len(contacts)} of "
                             f"{k} contacts {p['min_separation_m'] / MM:g} mm apart in {TRIES_PER_CONTACT * k} "
                             f"tries; lower contacts_per_frame or min_separation_mm")
        yield tuple(contacts)


def _path(p, rng, grid, n):
    """Constant speed along the waypoints; depth ramps linearly over the first and last `ramp_frames` frames."""
    points = np.array([w.metres(grid) for w in p["waypoints"]])
    lengths = np.hypot(*np.diff(points, axis=0).T)
    arc = np.concatenate([[0.0], np.cumsum(lengths)])
    ramp = p["ramp_frames"]
    for i in range(n):
        s = arc[-1] * i / (n - 1)
        x, y = np.interp(s, arc, points[:, 0]), np.interp(s, arc, points[:, 1])
        scale = min(1.0, (i + 1) / ramp, (n - i) / ramp) if ramp else 1.0
        yield (Contact(float(x), float(y), p["depth_m"] * scale, p["shape"], p["shear_m"]),)


_GENERATORS = {"rest": _rest, "press": _press, "contacts": _contacts, "press_grid": _press_grid,
               "random_presses": _random_presses, "path": _path}


# --- checks against the sensor's surface ----------------------------------------------------------------------------

def _check_margin(p, where: str, grid: BinGrid) -> None:
    if 2 * p["margin_m"] >= min(grid.width_m, grid.length_m):
        raise SceneError(f"{where}.margin_mm ({p['margin_m'] / MM:g} mm) leaves no room on the {grid.width_m / MM:g} "
                         f"x {grid.length_m / MM:g} mm surface: it must be less than half its shorter side")


def _check_press_grid(p, where: str, grid: BinGrid) -> None:
    """The margin leaves room, and the jitter keeps every press centre on the surface."""
    _check_margin(p, where, grid)
    spacing = min((grid.width_m - 2 * p["margin_m"]) / p["cols"], (grid.length_m - 2 * p["margin_m"]) / p["rows"])
    limit = p["margin_m"] + 0.5 * spacing
    if p["jitter_m"] > limit:
        raise SceneError(f"{where}.jitter_mm ({p['jitter_m'] / MM:g} mm) would move presses off the surface: it must "
                         f"be at most margin_mm plus half the grid spacing, {limit / MM:.4g} mm here")


def _check_random_presses(p, where: str, grid: BinGrid) -> None:
    """The margin leaves room, and the most contacts of a frame can be min_separation apart in the rectangle the
    centres are drawn from (necessary: no two farther apart than its diagonal, and the discs of diameter
    min_separation around them, disjoint, inside the rectangle grown by half that)."""
    if p["region"] == "surface":
        _check_margin(p, where, grid)
        outside = -p["margin_m"]
    else:
        outside = max(-p["edge_band_m"][0], 0.0)
        reach = contact_radius_m(p["shape"], p["depth_m"][1])
        if p["edge_band_m"][1] <= -reach:
            raise SceneError(f"{where}.edge_band_mm ({p['edge_band_m'][0] / MM:g} to {p['edge_band_m'][1] / MM:g} mm) "
                             f"lies wholly beside the surface, farther out than the {reach / MM:.3g} mm the contact "
                             f"reaches at its deepest: every press would press nothing; its upper end must be above "
                             f"-{reach / MM:.3g} mm")
    box = (grid.width_m + 2 * outside, grid.length_m + 2 * outside)
    k, separation = p["contacts_per_frame"][1], p["min_separation_m"]
    if k > 1 and (separation > math.hypot(*box)
                  or k * math.pi / 4 * separation**2 > (box[0] + separation) * (box[1] + separation)):
        raise SceneError(f"{where}.min_separation_mm ({separation / MM:g} mm): {k} contacts that far apart cannot fit "
                         f"in the {box[0] / MM:.4g} x {box[1] / MM:.4g} mm the centres are drawn from; lower "
                         f"min_separation_mm or contacts_per_frame")


def _check_touches(place: Place, shape: Sphere | FlatPunch, depth_m: float, where: str, grid: BinGrid) -> None:
    """A contact must touch the surface at its deepest (reach_problem). Scenes are in mm of the reference sensor's
    surface, and on a smaller one (a 24.5 mm strip) most of the demo scene's presses were off it, accepted without a
    word, with no force at all (found in review)."""
    problem = reach_problem(grid, *place.metres(grid), shape, depth_m)
    if problem is not None:
        why = ("fractions of the surface's width and length beyond 0 to 1 lie beside it" if place.fraction else
               "positions are in mm from the surface's corner; a scene made for another sensor may not fit this one")
        raise SceneError(f"{where}: {problem} ({why})")


def _check_press(p, where: str, grid: BinGrid) -> None:
    _check_touches(p["place"], p["shape"], max(p["depths_m"]), where, grid)


def _check_contacts(p, where: str, grid: BinGrid) -> None:
    for i, (place, contact) in enumerate(p["contacts"]):
        _check_touches(place, contact.shape, contact.depth_m, f"{where}.contacts[{i}]", grid)


def _check_path(p, where: str, grid: BinGrid) -> None:
    """Every waypoint within reach of the surface at the path's depth; so then is every place between two of them
    (the surface grown by that reach is convex). The demo scene's path ran beside a smaller surface unchecked, most
    of its frames pressing nothing."""
    key = "waypoints_fraction" if p["waypoints"][0].fraction else "waypoints_mm"
    for i, waypoint in enumerate(p["waypoints"]):
        _check_touches(waypoint, p["shape"], p["depth_m"], f"{where}.{key}[{i}]", grid)


_SURFACE_CHECKS = {"press_grid": _check_press_grid, "random_presses": _check_random_presses, "press": _check_press,
                   "contacts": _check_contacts, "path": _check_path}


# --- contacts that overlap ------------------------------------------------------------------------------------------

def _overlapping_contacts(p, where: str, grid: BinGrid) -> str | None:
    """Two contacts of the frame whose contact areas overlap (centres closer than their contact radii together). A
    contact at depth 0 presses nothing, a flat punch's radius notwithstanding."""
    pressing = [(i, c) for i, c in enumerate(_placed(p["contacts"], grid)) if c.depth_m > 0]
    for (i, a), (j, b) in itertools.combinations(pressing, 2):
        apart = math.hypot(a.x_m - b.x_m, a.y_m - b.y_m)
        reach = contact_radius_m(a.shape, a.depth_m) + contact_radius_m(b.shape, b.depth_m)
        if apart < reach:
            return (f"{where}.contacts[{i}] and contacts[{j}] overlap: {apart / MM:.3g} mm apart, closer than their "
                    f"contact radii together ({reach / MM:.3g} mm)")
    return None


def _overlapping_random_presses(p, where: str, _grid: BinGrid) -> str | None:
    """Frames of several presses whose min_separation lets two contact areas overlap at the deepest press."""
    reach = 2 * contact_radius_m(p["shape"], p["depth_m"][1])
    if p["contacts_per_frame"][1] > 1 and p["min_separation_m"] < reach:
        return (f"{where}.min_separation_mm ({p['min_separation_m'] / MM:g} mm) lets two contacts overlap: at the "
                f"deepest press their contact radii add up to {reach / MM:.3g} mm")
    return None


_OVERLAP_CHECKS = {"contacts": _overlapping_contacts, "random_presses": _overlapping_random_presses}


# --- the scene ------------------------------------------------------------------------------------------------------

@dataclass(frozen=True)
class Scene:
    """A parsed scene: name, seed, timeline segments, effect specs. `len(scene)` is its frame count."""

    name: str
    description: str
    seed: int
    segments: tuple[Segment, ...]
    effects: tuple[EffectSpec, ...]
    source: str
    frame_limit: int | None = None

    def __len__(self) -> int:
        total = sum(s.n_frames for s in self.segments)
        return total if self.frame_limit is None else min(total, self.frame_limit)

    def limited(self, frames: int) -> Scene:
        """The first `frames` frames of this scene (same contacts and effects as the full scene's prefix); never
        longer than the scene already is."""
        if not is_whole_number(frames):
            raise SceneError(f"the frame limit must be an integer >= 1, got {frames!r}")
        frames = int(frames)  # a NumPy integer would reach the JSON records of a data set or a model
        return replace(self, frame_limit=frames if self.frame_limit is None else min(frames, self.frame_limit))

    def contacts(self, sensor: SensorDescription) -> Iterator[tuple[Contact, ...]]:
        """The contacts of each frame, in order (lazy; one tuple per frame); validates the scene first."""
        self.validate(sensor)
        for _, frames in self._played_segments(sensor.grid):
            yield from frames

    def _played_segments(self, grid: BinGrid) -> Iterator[tuple[Segment, Iterator[tuple[Contact, ...]]]]:
        """Each segment the scene plays, with the contacts of its frames within the frame limit, drawn from its own
        random stream (module docstring): what contacts() yields and what _check_room draws beforehand. No frame past
        the limit is made: random presses could fail on one that is never played (found in review)."""
        left = len(self)
        for i, segment in enumerate(self.segments):
            if left <= 0:
                return
            yield segment, itertools.islice(segment.frames(np.random.default_rng([self.seed, 0, i]), grid), left)
            left -= segment.n_frames

    def check_playable(self, sensor: SensorDescription, ground_truth: GroundTruthModel) -> None:
        """SceneError for a scene that `sensor` cannot play with `ground_truth` labelling it, before any frame: what
        `validate` checks, contacts the model would count twice (`_check_overlaps`), and random presses that find no
        room for their separation (`_check_room`)."""
        self.validate(sensor)
        self._check_overlaps(ground_truth, sensor.grid)
        self._check_room(sensor.grid)

    def _check_room(self, grid: BinGrid) -> None:
        """Random presses of several contacts apart find no room only as their frames are made: a data set failed in
        its middle, a live graph's cameras once it ran (found in review). Their contacts (no physics: 0.01 s for
        multi_contact's 240 frames) are drawn once here, as contacts() draws them."""
        for segment, frames in self._played_segments(grid):
            p = segment.params
            if segment.kind == "random_presses" and p["contacts_per_frame"][1] > 1 and p["min_separation_m"] > 0:
                for _ in frames:
                    pass

    def validate(self, sensor: SensorDescription) -> None:
        """Check what needs the sensor, with errors naming the file and key: every indenter and depth within the
        contact models' range (contact.press_problem, each contact against its own indenter), shears at most the
        compliant gel's thickness, margins, jitter and separations that fit the surface, effect cameras among the
        sensor's."""
        for segment in self.segments:
            for extremes in segment.extremes:
                problem = press_problem(sensor, extremes.shape, extremes.depth_m)
                if problem is not None:
                    raise SceneError(f"{extremes.where}: {problem}")
                problem = shear_problem(sensor, extremes.shear_m)
                if problem is not None:
                    raise SceneError(f"{extremes.where}.shear_mm: {problem}")
            if segment.kind in _SURFACE_CHECKS:
                _SURFACE_CHECKS[segment.kind](segment.params, segment.where, sensor.grid)
        ctx = self.effect_context(sensor)
        for effect in self.effects:
            effect.camera_mask(ctx)

    def _check_overlaps(self, ground_truth: GroundTruthModel, grid: BinGrid) -> None:
        """SceneError where two contacts of a frame on `grid`'s surface may overlap and `ground_truth` computes each
        contact alone and adds their forces (GroundTruthModel.adds_contacts): it would count the shared part twice."""
        if not ground_truth.adds_contacts:
            return
        for segment in self.segments:
            check = _OVERLAP_CHECKS.get(segment.kind)
            problem = check(segment.params, segment.where, grid) if check else None
            if problem:
                raise SceneError(f"{problem}: the {ground_truth.name} ground-truth model computes each contact alone "
                                 "and adds their forces, counting the overlap twice; move them apart, or label the "
                                 "scene with the numerical model (tactile-sim generate or render --model numerical; "
                                 "the simulated camera node and training from a scene have the "
                                 "analytic one only)")

    def effect_context(self, sensor: SensorDescription) -> EffectContext:
        out = sensor.cameras[0].output_size
        return EffectContext(camera_ids=sensor.camera_ids, image_shape=(out[1], out[0]),
                             frame_rate_hz=sensor.frame_rate_hz, seed=self.seed, where=self.source)


def scenes_directory() -> Path:
    """Where the installed scenes live: tactile_bringup's config/scenes. Not next to $TACTILE_SENSOR_CONFIG: a user's
    own sensor file elsewhere left every scene name unknown ("installed scenes are []", found in review)."""
    return installed_config_dir() / "scenes"


def parse_scene(raw, source: str = "scene") -> Scene:
    """A Scene from an already loaded YAML mapping (`source` names it in errors)."""
    n = _fields(raw, source)
    name = n.raw("name", required=True)
    if not (isinstance(name, str) and SCENE_NAME.fullmatch(name)):
        raise SceneError(f"{source}.name must be a file name of letters, digits, '_', '-' and '.' (not first), at "
                         f"most 100 characters (previews are named after it), got {name!r}")
    description = n.raw("description", "")
    description = "" if description is None else description  # `description:` with nothing after it
    if not isinstance(description, str):
        raise SceneError(f"{source}.description must be text, got {description!r}")
    seed = n.count("seed", low=0)
    default_shape = _indenter(n.raw("indenter"), f"{source}.indenter") if n.has("indenter") else Sphere(0.005)
    timeline = n.raw("timeline", required=True)
    if not (isinstance(timeline, list) and timeline):
        raise SceneError(f"{source}.timeline must be a non-empty list of segments {list(SEGMENT_KINDS)}")
    segments = tuple(_parse_segment(e, f"{source}.timeline[{i}]", default_shape) for i, e in enumerate(timeline))
    total = 0
    for segment in segments:
        total += segment.n_frames
        if total > MAX_FRAMES:
            raise SceneError(f"{segment.where}: the scene reaches {total} frames here, more than {MAX_FRAMES}")
    effects_raw = n.raw("effects", [])
    if not isinstance(effects_raw, list):
        raise SceneError(f"{source}.effects must be a list of effects, got {effects_raw!r}")
    effects = tuple(parse_effect(e, f"{source}.effects[{i}]") for i, e in enumerate(effects_raw))
    for i, effect in enumerate(effects):
        if effect.frames is not None and effect.frames[0] >= total:
            raise SceneError(f"{source}.effects[{i}]: effect {effect.name!r} starts at frame {effect.frames[0]}, "
                             f"but the scene has {total} frames (0 to {total - 1}): it would never act")
    n.finish()
    return Scene(name=name, description=description, seed=seed, segments=segments, effects=effects, source=source)


def load_scene(path_or_name: str | os.PathLike, sensor: SensorDescription | None = None) -> Scene:
    """Read a scene file, or an installed scene by name ("paper_grid" -> <share>/config/scenes/paper_grid.yaml).

    With `sensor`, also checks what depends on it (Scene.validate); the simulator always does before streaming.
    """
    path = Path(path_or_name)
    # A plain name may be an installed scene; a path (with a directory, even "./") names a file only: Path("./x")
    # is Path("x"), so "./demo.yaml" missing here read the installed demo without a word (review).
    given = os.fspath(path_or_name)
    plain_name = "/" not in given and os.sep not in given
    if not path.is_file() and path.suffix in ("", ".yaml") and plain_name:
        try:
            path = scenes_directory() / f"{path.stem}.yaml"
        except SensorConfigError as exc:  # where the scenes would be installed: a scene's error, as for the rest
            raise SceneError(f"no scene file {path_or_name!r}, and {exc}") from exc
        if not path.exists():
            known = sorted(p.stem for p in path.parent.glob("*.yaml"))
            raise SceneError(f"no scene file {path_or_name!r} and no installed scene of that name; installed scenes "
                             f"are {known} (in {path.parent})")
    raw = load_yaml_file(path, "scene file", SceneError)
    scene = parse_scene(raw, str(path))
    if sensor is not None:
        scene.validate(sensor)
    return scene
