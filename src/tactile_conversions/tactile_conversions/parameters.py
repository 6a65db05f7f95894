"""Node parameters that take what a command line gives them, checked once, with errors naming the parameter.

rcl reads `-p rate_hz:=30` as an integer and `-p source:=2` as one too; a parameter declared with a float or
string default refuses them (InvalidParameterTypeException) and the node dies at start-up. Declared with
`DYNAMIC`, a parameter takes any type, and the node converts it itself. A check written `x <= 0` lets NaN through
(every comparison with NaN is false): `positive_float` refuses NaN and infinities.
"""

from __future__ import annotations

import math

from rcl_interfaces.msg import ParameterDescriptor
from rclpy.node import Node

#: The descriptor of a parameter whose type the node checks and converts itself.
DYNAMIC = ParameterDescriptor(dynamic_typing=True)


def positive_float(node: Node, name: str, default: float, *, allow_zero: bool = False) -> float:
    """Declare parameter `name` and return its value: a finite number > 0 (>= 0 with `allow_zero`), as a float.

    Integers are taken as floats; anything else (a string, a bool, NaN, an infinity, a number out of range) raises
    ValueError naming the node and the parameter.
    """
    value = node.declare_parameter(name, default, DYNAMIC).value
    bound = ">= 0" if allow_zero else "> 0"
    if isinstance(value, bool) or not isinstance(value, int | float):
        raise ValueError(f"{node.get_name()}: parameter {name} must be a number {bound}, got {value!r}")
    value = float(value)
    if not (math.isfinite(value) and (value >= 0 if allow_zero else value > 0)):
        raise ValueError(f"{node.get_name()}: parameter {name} must be a finite number {bound}, got {value}")
    return value
