"""What counts as a number and as a whole number, for every check of the stack's inputs alike.

Python counts `True` as the integer 1, and every comparison with NaN is false, so `value > 0` lets NaN through and
`isinstance(value, int)` lets a YAML `yes` through. These two predicates close both holes once. NumPy scalars are
numbers too (`numbers.Real` and `numbers.Integral` include them), so values read from arrays pass the same checks.
"""

from __future__ import annotations

import math
import numbers


def is_number(value) -> bool:
    """A finite real number (int, float or a NumPy scalar), not a bool; an integer too large for a float is not."""
    if not isinstance(value, numbers.Real) or isinstance(value, bool):
        return False
    try:
        return math.isfinite(value)
    except OverflowError:  # math.isfinite(10**400)
        return False


def is_whole_number(value, low: int = 1) -> bool:
    """An integer (Python's or NumPy's) >= `low`, not a bool."""
    return isinstance(value, numbers.Integral) and not isinstance(value, bool) and value >= low
