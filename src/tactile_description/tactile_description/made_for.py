"""What a model was trained for, or a data set made for: the parts of a sensor description that shape its images and
forces, kept with the model (model.json) and the data set (meta.json) so that a description changed since can be
named field by field.

Left out: the sensor's name, TF frame, frame rate and file. Renaming a sensor or running its cameras at another rate
changes no image the model sees.
"""

from __future__ import annotations

import dataclasses
import json
import math

from tactile_description.sensor import SensorDescription
from tactile_description.value_checks import is_number

#: The parts of a sensor description that a model learns: the bin grid, the gel, its particles and the cameras.
PHYSICAL_PARTS = ("grid", "gel_layers", "particles", "cameras")

#: Changed fields named in full by `changes_text`; the rest are counted.
NAMED_CHANGES = 4


def physical_fields(sensor: SensorDescription) -> dict:
    """The PHYSICAL_PARTS of `sensor` as JSON values (SI units, as the description holds them; tuples as lists)."""
    every_field = dataclasses.asdict(sensor)
    return json.loads(json.dumps({part: every_field[part] for part in PHYSICAL_PARTS}))


def made_for_problem(fields) -> str:
    """What is wrong with `fields` as `physical_fields` read back from a file ("" if nothing): every part present, the
    grid and the particles mappings, the gel layers and the cameras lists of mappings, each camera with its id."""
    if not isinstance(fields, dict):
        return f"must be a mapping of {list(PHYSICAL_PARTS)}, got {fields!r}"
    missing = [part for part in PHYSICAL_PARTS if part not in fields]
    if missing:
        return f"lacks {missing}"
    if not (isinstance(fields["grid"], dict) and isinstance(fields["particles"], dict)):
        return "grid and particles must be mappings"
    for part in ("gel_layers", "cameras"):
        if not (isinstance(fields[part], list) and all(isinstance(item, dict) for item in fields[part])):
            return f"{part} must be a list of mappings, got {fields[part]!r}"
    if not all(isinstance(camera.get("camera_id"), str) for camera in fields["cameras"]):
        return "every camera must have its camera_id"
    return ""


def changed_fields(before, now, where: str = "") -> list[str]:
    """The fields whose values differ between two `physical_fields`, as paths such as "cameras[cam1].position_m" or
    "gel_layers[protective_top].youngs_modulus_pa". Cameras are matched by id, in whatever order a description lists
    them (the model matches its inputs by camera id); gel layers by their place in the stack (named by their name
    where it stayed the same). A key that only one of them has is not compared: a field that a later version adds,
    with its default, does not make every model trained before it look out of date. Numbers within 1e-9 of their size
    are equal: the same value converted to SI units another way."""
    if isinstance(before, dict) and isinstance(now, dict):
        return [change for key in before if key in now
                for change in changed_fields(before[key], now[key], f"{where}.{key}" if where else key)]
    if isinstance(before, list) and isinstance(now, list) and len(before) == len(now):
        pairs = _by_camera_id(before, now)
        if pairs is not None:
            return [change for camera_id, (old, new) in pairs.items()
                    for change in changed_fields(old, new, f"{where}[{camera_id}]")]
        if all(is_number(v) for v in before + now):  # a vector (a position, lens distortion) is one field
            return [] if all(map(_same_number, before, now)) else [where]
        return [change for index, (old, new) in enumerate(zip(before, now, strict=True))
                for change in changed_fields(old, new, f"{where}[{_layer_name(old, new, index)}]")]
    if is_number(before) and is_number(now):
        return [] if _same_number(before, now) else [where]
    return [] if before == now else [where]


def _same_number(a, b) -> bool:
    return math.isclose(a, b, rel_tol=1e-9, abs_tol=0.0)


def _layer_name(before, now, index: int) -> str:
    """How a gel layer is named in a path: by its name where both have the same one, else by its place."""
    if isinstance(before, dict) and isinstance(now, dict) and isinstance(before.get("name"), str) \
            and before.get("name") == now.get("name"):
        return before["name"]
    return str(index)


def _by_camera_id(before: list, now: list) -> dict[str, tuple[dict, dict]] | None:
    """Two lists of cameras paired by camera id, in `before`'s order; None unless both are lists of cameras with the
    same ids, each once."""
    def by_id(cameras: list) -> dict | None:
        if cameras and all(isinstance(c, dict) and isinstance(c.get("camera_id"), str) for c in cameras):
            return {c["camera_id"]: c for c in cameras}
        return None

    old, new = by_id(before), by_id(now)
    if old is None or new is None or set(old) != set(new) or len(old) != len(before):
        return None
    return {camera_id: (camera, new[camera_id]) for camera_id, camera in old.items()}


def changes_text(changes: list[str]) -> str:
    """`changed_fields` for a message: the first NAMED_CHANGES, then how many more."""
    more = len(changes) - NAMED_CHANGES
    return ", ".join(changes[:NAMED_CHANGES]) + (f" and {more} more" if more > 0 else "")
