"""What a model was trained for: the parts of a sensor description that shape its images and forces, kept with the
model (model.json) so that a description changed since training can be named field by field.

Left out: the sensor's name, TF frame, frame rate and file. Renaming a sensor or running its cameras at another rate
changes no image the model sees.
"""

from __future__ import annotations

import dataclasses
import json

from tactile_description.sensor import SensorDescription

#: The parts of a sensor description that a model learns: the bin grid, the gel, its particles and the cameras.
PHYSICAL_PARTS = ("grid", "gel_layers", "particles", "cameras")

#: Changed fields named in full by `changes_text`; the rest are counted.
NAMED_CHANGES = 4


def physical_fields(sensor: SensorDescription) -> dict:
    """The PHYSICAL_PARTS of `sensor` as JSON values (SI units, as the description holds them; tuples as lists)."""
    every_field = dataclasses.asdict(sensor)
    return json.loads(json.dumps({part: every_field[part] for part in PHYSICAL_PARTS}))


def changed_fields(before, now, where: str = "") -> list[str]:
    """The fields whose values differ between two `physical_fields`, as paths such as "cameras[cam1].position_m" or
    "gel_layers[top].youngs_modulus_pa" (a camera or layer named by its id or name where both have the same one, else
    by its index). A key that only one of them has is not compared: a field that a later version adds, with its
    default, does not make every model trained before it look out of date."""
    if isinstance(before, dict) and isinstance(now, dict):
        return [change for key in before if key in now
                for change in changed_fields(before[key], now[key], f"{where}.{key}" if where else key)]
    if isinstance(before, list) and isinstance(now, list) and len(before) == len(now) and \
            not all(isinstance(v, (int, float)) for v in before + now):
        return [change for index, (old, new) in enumerate(zip(before, now, strict=True))
                for change in changed_fields(old, new, f"{where}[{_item_name(old, new, index)}]")]
    return [] if before == now else [where]


def _item_name(before, now, index: int) -> str:
    """How a list item is named in a path: a camera by its id, a gel layer by its name, where both agree."""
    for key in ("camera_id", "name"):
        if isinstance(before, dict) and isinstance(now, dict) and before.get(key) == now.get(key) is not None:
            return str(before[key])
    return str(index)


def changes_text(changes: list[str]) -> str:
    """`changed_fields` for a message: the first NAMED_CHANGES, then how many more."""
    more = len(changes) - NAMED_CHANGES
    return ", ".join(changes[:NAMED_CHANGES]) + (f" and {more} more" if more > 0 else "")
