"""Node parameters that take what a command line gives them, checked once, with errors naming the parameter.

rcl reads `-p rate_hz:=30` as an integer and `-p source:=2` as one too; a parameter declared with a float or
string default refuses them (InvalidParameterTypeException) and the node dies at start-up with a traceback, as a
parameter declared with an integer default does with `-p threads:=2.0`. Declared with `DYNAMIC`, a parameter takes
any type, and the node checks and converts it itself. A check written `x <= 0` lets NaN through
(every comparison with NaN is false): `positive_float` refuses NaN and infinities.

A timer's period is passed to rcl as int64 nanoseconds: rclpy fails on a longer one than 292 years with a pybind
TypeError that names no parameter (`-p camera_timeout_s:=1e12`, `-p rate_hz:=1e-12`). `period_s` and `rate_hz`, for
the parameters a timer is built from, take at most a period of `MAX_PERIOD_S` (a day), far below that. A period is
also rounded to whole nanoseconds: `-p rate_hz:=1e12` made a timer of period 0, which fires on every spin, and
`-p camera_timeout_s:=1e-10` one that held a core; `rate_hz` takes at most `MAX_RATE_HZ`, `period_s` at least
`MIN_PERIOD_S`, its period.

Switches and names (`boolean`, `text`) are declared with `DYNAMIC` too: declared with their type, `-p loop:=0` or
`-p scene:=3` ended in rclpy's InvalidParameterTypeException traceback, which names neither the node nor what the
parameter takes. Every refusal is a `ParameterError`, which `node_main.run_node` reports in one line on stderr before
it ends the node with exit status 2, as a command line refuses its input.
"""

from __future__ import annotations

import contextlib

from rcl_interfaces.msg import ParameterDescriptor
from rclpy.node import Node

from tactile_description import SensorDescription, load_sensor
from tactile_description.sensor import MAX_FRAME_RATE_HZ, MIN_FRAME_RATE_HZ, SensorConfigError
from tactile_description.value_checks import is_number, is_whole_number

#: The descriptor of a parameter whose type the node checks and converts itself, once, at start-up: read-only after it.
#: The nodes read their parameters when they start; `ros2 param set ... rate_hz nan` reported success, changed nothing
#: and left NaN in the parameter for anyone who queried it (review). Now such a change is refused ("Trying to set a
#: read-only parameter").
DYNAMIC = ParameterDescriptor(dynamic_typing=True, read_only=True)

#: The rates that rate_hz takes (cameras, RViz markers): those a sensor description's frame_rate_hz may give, one a day
#: to 1 kHz.
MIN_RATE_HZ, MAX_RATE_HZ = MIN_FRAME_RATE_HZ, MAX_FRAME_RATE_HZ
#: The longest period or timeout that period_s takes: one day, that of the lowest rate.
MAX_PERIOD_S = 86_400.0
#: The shortest period or timeout that period_s takes: that of the highest rate.
MIN_PERIOD_S = 1.0 / MAX_RATE_HZ


class ParameterError(ValueError):
    """A parameter value that a node refuses at start-up; its message names the node and the parameter."""


def positive_float(node: Node, name: str, default: float, *, allow_zero: bool = False) -> float:
    """Declare parameter `name` and return its value: a finite number > 0 (>= 0 with `allow_zero`), as a float.

    Integers are taken as floats; anything else (a string, a bool, NaN, an infinity, a number out of range) raises
    ParameterError naming the node and the parameter.
    """
    value = node.declare_parameter(name, default, DYNAMIC).value
    bound = ">= 0" if allow_zero else "> 0"
    if not (is_number(value) and (value >= 0 if allow_zero else value > 0)):
        raise ParameterError(f"{node.get_name()}: parameter {name} must be a finite number {bound}, got {value!r}")
    return float(value)


def whole_number(node: Node, name: str, default: int, low: int = 1, high: int | None = None) -> int:
    """Declare parameter `name` and return its value: a whole number >= `low` (and <= `high` if given).

    Anything else (a float, even 2.0; a string; a bool) raises ParameterError naming the node and the parameter.
    """
    value = node.declare_parameter(name, default, DYNAMIC).value
    if not is_whole_number(value, low) or (high is not None and value > high):
        bound = f">= {low}" if high is None else f"from {low} to {high}"
        raise ParameterError(f"{node.get_name()}: parameter {name} must be a whole number {bound}, got {value!r}")
    return value


def period_s(node: Node, name: str, default: float) -> float:
    """positive_float for a period or timeout that a timer is built from: also from MIN_PERIOD_S to MAX_PERIOD_S."""
    value = positive_float(node, name, default)
    if value < MIN_PERIOD_S:
        raise ParameterError(f"{node.get_name()}: parameter {name} must be at least {MIN_PERIOD_S:g} s, got {value!r}")
    if value > MAX_PERIOD_S:
        raise ParameterError(f"{node.get_name()}: parameter {name} must be at most {MAX_PERIOD_S:g} s (one day), "
                             f"got {value!r}")
    return value


def rate_hz(node: Node, name: str, default: float) -> float:
    """positive_float for a rate that a timer's period (its inverse) is built from: also from MIN_RATE_HZ to
    MAX_RATE_HZ."""
    value = positive_float(node, name, default)
    if value < MIN_RATE_HZ:
        raise ParameterError(f"{node.get_name()}: parameter {name} must be at least {MIN_RATE_HZ:.6g} Hz (once a "
                             f"day), got {value!r}")
    if value > MAX_RATE_HZ:
        raise ParameterError(f"{node.get_name()}: parameter {name} must be at most {MAX_RATE_HZ:g} Hz, got {value!r}")
    return value


def boolean(node: Node, name: str, default: bool) -> bool:
    """Declare parameter `name` and return its value: true or false. Anything else (`-p loop:=0`, a string) raises
    ParameterError naming the node and the parameter."""
    value = node.declare_parameter(name, default, DYNAMIC).value
    if not isinstance(value, bool):
        raise ParameterError(f"{node.get_name()}: parameter {name} must be a bool (true or false), got {value!r}")
    return value


def text(node: Node, name: str, default: str) -> str:
    """Declare parameter `name` and return its value: a string. Anything else (`-p scene:=3`: quote a number as a
    string, `-p scene:="'3'"`) raises ParameterError naming the node and the parameter."""
    value = node.declare_parameter(name, default, DYNAMIC).value
    if not isinstance(value, str):
        raise ParameterError(f"{node.get_name()}: parameter {name} must be a string, got {value!r}")
    return value


def sensor_description(node: Node) -> SensorDescription:
    """Declare parameter `sensor_config` and return the sensor description it names (empty: the default, see
    tactile_description.load_sensor). A description that cannot be read or is not valid raises ParameterError naming
    the node, the parameter and what is wrong with the file."""
    path = text(node, "sensor_config", "")
    with refused_as(node, "parameter sensor_config", SensorConfigError):
        return load_sensor(path or None)


def log_sensor_description(node: Node, sensor: SensorDescription) -> None:
    """Say which sensor description a node uses: a misspelt parameter (`-p sensor_configs:=...`) left it on the default
    sensor without a word (found in review). Logged once the node has accepted all its parameters, so that a refusal
    stays one line."""
    node.get_logger().info(f"sensor description {sensor.name!r} ({sensor.n_cameras} cameras, {sensor.grid.rows} x "
                           f"{sensor.grid.cols} bins) from {sensor.source}")


@contextlib.contextmanager
def refused_as(node: Node, parameters: str, *errors: type[Exception]):
    """Turn `errors` raised inside into a ParameterError "<node>: <parameters>: <error>": for what parameters name
    and the node can only find out by using it (a file that cannot be read, a model of another sensor)."""
    try:
        yield
    except errors as exc:
        raise ParameterError(f"{node.get_name()}: {parameters}: {exc}") from exc
