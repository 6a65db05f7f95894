"""ROS 2 message type names ("sensor_msgs/msg/Image") -> what `rosbags` and rclpy need to handle the type.

A bag stores, per topic, the type name, its full definition text and its type hash (RIHS01), which `ros2 bag`
checks. `rosbags` knows the standard types of each distribution; the stack's own types (tactile_msgs) are
registered from the `.msg` files the package installs, so the definition and hash written into a bag are those
of the installed interface (the tests compare the hash with the one rosidl generated).
"""

from __future__ import annotations

import importlib
from collections.abc import Iterable
from pathlib import Path

from ament_index_python.packages import PackageNotFoundError, get_package_share_directory
from rosbags.typesys import Stores, get_types_from_msg, get_typestore
from rosbags.typesys.store import Typestore

#: The distribution whose standard types (and bag format) we write: the one `make setup` installs.
STORE = Stores.ROS2_KILTED


class MessageTypeError(ValueError):
    """A message type that cannot be written, read or published here."""


def split_type_name(msgtype: str) -> tuple[str, str]:
    """'sensor_msgs/msg/Image' -> ('sensor_msgs', 'Image'); anything else raises MessageTypeError."""
    parts = msgtype.split("/")
    if len(parts) != 3 or parts[1] != "msg" or not all(parts):
        raise MessageTypeError(f"message type {msgtype!r}: expected 'package/msg/Name', e.g. 'sensor_msgs/msg/Image'")
    return parts[0], parts[2]


def message_class(msgtype: str) -> type:
    """The rclpy message class of a type name (what a publisher or deserialize_message needs)."""
    package, name = split_type_name(msgtype)
    try:
        module = importlib.import_module(f"{package}.msg")
    except ImportError as exc:
        raise MessageTypeError(f"message type {msgtype}: the Python package {package} is not installed; install "
                               f"it (e.g. ros-kilted-{package.replace('_', '-')}) or source its workspace") from exc
    cls = getattr(module, name, None)
    if cls is None:
        raise MessageTypeError(f"message type {msgtype}: {package} has no message {name}")
    return cls


def package_msg_dir(package: str) -> Path:
    try:
        return Path(get_package_share_directory(package)) / "msg"
    except PackageNotFoundError as exc:
        raise MessageTypeError(f"message package {package} is not installed (not in the ament index): source the "
                               "workspace that builds it (scripts/env.sh here)") from exc


def register_package(typestore: Typestore, package: str) -> None:
    """Register every message of an installed package from its share/<package>/msg/*.msg files."""
    types = {}
    for path in sorted(package_msg_dir(package).glob("*.msg")):
        types.update(get_types_from_msg(path.read_text(), f"{package}/msg/{path.stem}"))
    if not types:
        raise MessageTypeError(f"message package {package} installs no .msg files in {package_msg_dir(package)}")
    typestore.register(types)


def bag_typestore(msgtypes: Iterable[str] = ()) -> Typestore:
    """The standard types of ROS 2 Kilted plus the packages of any of `msgtypes` it does not know yet."""
    typestore = get_typestore(STORE)
    add_types(typestore, msgtypes)
    return typestore


def add_types(typestore: Typestore, msgtypes: Iterable[str]) -> None:
    """Register the package of each of `msgtypes` that `typestore` does not know yet (from its .msg files)."""
    for msgtype in msgtypes:
        package, name = split_type_name(msgtype)
        if msgtype not in typestore.fielddefs:
            register_package(typestore, package)
        if msgtype not in typestore.fielddefs:
            raise MessageTypeError(f"message type {msgtype}: package {package} has no {name}.msg")
