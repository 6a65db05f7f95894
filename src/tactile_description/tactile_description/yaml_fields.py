"""Reading the stack's YAML files (sensor descriptions, simulator scenes): the file itself, then typed,
range-checked fields, with errors that name the file and the key path.

Used by every YAML file of the stack, so that an unreadable file, a typo or an impossible value is reported the
same way everywhere: which file, which key, what was expected, what was found.
"""

from __future__ import annotations

import difflib
import math
import os
import re
from collections.abc import Hashable
from pathlib import Path

import yaml

from tactile_description.value_checks import is_number, is_whole_number

#: The most values (scalars, lists and mappings, each alias counted as often as it is used) a YAML file of the stack
#: may expand to: the largest shipped file has a few hundred. Ten aliases of ten aliases, nine levels deep, are a
#: 600-byte file of 10**9 values, which any walk over them (a check, an error message's repr) runs out of memory on.
MAX_YAML_VALUES = 1_000_000


class YamlLoader(yaml.SafeLoader):
    """PyYAML's safe loader, which reads numbers as YAML 1.2 does.

    PyYAML follows YAML 1.1, whose float needs a dot and a signed exponent: it reads `1e-3` as the string "1e-3",
    which every number check then refuses with a confusing message. Here a float needs a dot or an exponent, so that
    `10` stays an integer (counts are checked to be whole numbers), and `.inf`, `.nan` and `1_000.5` are floats as
    before. YAML 1.1's integers and its base-60 numbers are gone: `012` is twelve, not the octal 10, and `1:30` and
    `1:30.5` are text, not 90 and 90.5 (octal is `0o12`, hexadecimal `0x1f`; digits may still be grouped, `10_000`).

    A key given twice in one mapping is refused (PyYAML keeps the last value: a scene's second `seed:` or `timeline:`
    silently replaced the first), naming both lines.
    """

    def construct_mapping(self, node, deep=False):
        first_seen = {}
        for key_node, _ in node.value:
            if key_node.tag == "tag:yaml.org,2002:merge":  # `<<: *anchor` may repeat keys: that is what it is for
                continue
            key = self.construct_object(key_node, deep=True)
            if not isinstance(key, Hashable):  # SafeLoader's own construct_mapping refuses it below
                continue
            if key in first_seen:
                raise yaml.constructor.ConstructorError(
                    "while constructing a mapping", node.start_mark,
                    f"found key {key!r} a second time (first on line {first_seen[key].line + 1})", key_node.start_mark)
            first_seen[key] = key_node.start_mark
        return super().construct_mapping(node, deep)


INT_TAG, FLOAT_TAG = "tag:yaml.org,2002:int", "tag:yaml.org,2002:float"
# YAML 1.2's numbers in place of PyYAML's YAML 1.1 rules (class docstring); digits may be grouped with `_`, as PyYAML
# allows. The resolvers are the loader's own, built from SafeLoader's, which stay as they are.
YamlLoader.yaml_implicit_resolvers = {
    first: [(tag, pattern) for tag, pattern in resolvers if tag not in (INT_TAG, FLOAT_TAG)]
    for first, resolvers in yaml.SafeLoader.yaml_implicit_resolvers.items()}
YAML12_INT = re.compile(r"^(?:[-+]?[0-9][0-9_]*|0o[0-7][0-7_]*|0x[0-9a-fA-F][0-9a-fA-F_]*)$")
YAML12_FLOAT = re.compile(
    r"^(?:[-+]?(?:(?:[0-9][0-9_]*\.[0-9_]*|\.[0-9][0-9_]*)(?:[eE][-+]?[0-9]+)?|[0-9][0-9_]*[eE][-+]?[0-9]+)"
    r"|[-+]?\.(?:inf|Inf|INF)|\.(?:nan|NaN|NAN))$")
YamlLoader.add_implicit_resolver(INT_TAG, YAML12_INT, list("-+0123456789"))
YamlLoader.add_implicit_resolver(FLOAT_TAG, YAML12_FLOAT, list("-+.0123456789"))


def _yaml12_int(loader: YamlLoader, node) -> int:
    """An integer as YAML 1.2 writes it: decimal (`012` is twelve), `0o` octal or `0x` hexadecimal. Also for an
    explicit `!!int`, whose YAML 1.1 forms (`0b101`, `1:30`) are refused naming the line."""
    text = loader.construct_scalar(node)
    digits = text.replace("_", "")
    base = {"0o": 8, "0x": 16}.get(digits[:2], 10)
    try:
        return int(digits[2:] if base != 10 else digits, base)
    except ValueError:
        raise yaml.constructor.ConstructorError(
            None, None, f"{text!r} is not an integer (YAML 1.2: decimal, 0o octal or 0x hexadecimal)",
            node.start_mark) from None


def _yaml12_float(loader: YamlLoader, node) -> float:
    """A float as YAML 1.2 writes it, also for an explicit `!!float` (on a decimal integer too, `!!float 12`), whose
    other text (`!!float abc`, YAML 1.1's `!!float 1:30`) is refused naming the line: PyYAML's own reader raised a
    ValueError or IndexError that named neither file nor key, or read 1:30 as 90 (review)."""
    text = loader.construct_scalar(node)
    if YAML12_FLOAT.match(text) or (YAML12_INT.match(text) and not text.startswith(("0o", "0x"))):
        special = text.lstrip("+-").lower()
        if special in (".inf", ".nan"):
            return float(("-" if text.startswith("-") else "") + special[1:])
        return float(text.replace("_", ""))
    raise yaml.constructor.ConstructorError(
        None, None, f"{text!r} is not a number (YAML 1.2: e.g. 1.5, 1e-3, .inf)", node.start_mark)


YamlLoader.add_constructor(INT_TAG, _yaml12_int)
YamlLoader.add_constructor(FLOAT_TAG, _yaml12_float)


def load_yaml_file(path: str | os.PathLike, what: str, error: type[Exception] = ValueError):
    """The content of the YAML file `path` (read with YamlLoader). A file that cannot be read, is not UTF-8 text or
    is not YAML raises `error` with a one-sentence message naming `what` ("sensor description") and the path."""
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8")  # YAML files are UTF-8, whatever the locale says
    except OSError as exc:
        raise error(f"cannot read {what} {path}: {exc.strerror or exc}") from exc
    except UnicodeDecodeError as exc:  # a ValueError, which the command lines would report without the file's name
        raise error(f"{what} {path} is not UTF-8 text (bad byte at offset {exc.start}); give a YAML file") from exc
    try:
        content = yaml.load(text, Loader=YamlLoader)  # a SafeLoader: builds no Python objects
    except yaml.YAMLError as exc:
        raise error(f"{what} {path} is not valid YAML: {exc}") from exc
    except RecursionError as exc:  # PyYAML's composer recurses once per level (a traceback: found in review)
        raise error(f"{what} {path} nests its lists or mappings too deeply for a YAML reader; no scene, sensor "
                    "description or camera sources file needs more than a few levels") from exc
    if _values_beyond(content, MAX_YAML_VALUES):
        raise error(f"{what} {path} expands to more than {MAX_YAML_VALUES} values through its aliases (*name); no "
                    "scene, sensor description or camera sources file needs that many")
    return content


def _values_beyond(content, limit: int) -> bool:
    """Whether `content` holds more than `limit` values, each alias counted as often as it is used; the walk stops
    at the limit, so that a file of aliases of aliases is refused in a bounded time."""
    pending, seen = [content], 0
    while pending:
        value = pending.pop()
        seen += 1
        if seen > limit:
            return True
        if isinstance(value, dict):
            pending += [*value.keys(), *value.values()]
        elif isinstance(value, list):
            pending += value
    return False


class YamlFields:
    """One YAML mapping; `finish()` rejects the keys no getter asked for (typos, unsupported options)."""

    def __init__(self, node, where: str, error: type[Exception] = ValueError):
        if not isinstance(node, dict):
            raise error(f"{where} must be a mapping, got {node!r}")
        self.node = node
        self.where = where
        self.error = error
        self._used: set[str] = set()

    def has(self, key: str) -> bool:
        return key in self.node

    def raw(self, key: str, default=None, required: bool = False):
        if key not in self.node:
            if required:  # naming a key like it: `bin_col: 20` was only "missing key 'bin_cols'" (walkthrough)
                unread = [k for k in self.node if isinstance(k, str) and k not in self._used]  # those read are known
                alike = difflib.get_close_matches(key, unread, n=1, cutoff=0.8)
                typo = f" ({alike[0]!r} is given: a typo?)" if alike else ""
                raise self.error(f"{self.where}: missing key {key!r}{typo}")
            return default
        self._used.add(key)
        return self.node[key]

    def child(self, key: str) -> YamlFields:
        """The nested mapping under `key` (required)."""
        return YamlFields(self.raw(key, required=True), f"{self.where}.{key}", self.error)

    def number(self, key: str, default=None, low: float = -math.inf, high: float = math.inf,
               positive: bool = False) -> float:
        value = self.raw(key, default, required=default is None)
        if not is_number(value) or not low <= value <= high or (positive and value <= 0):
            # "finite" said first: "in [-inf, inf], got inf" for yaw_deg 1e400 named no bound it broke (walkthrough)
            if positive:
                wanted = f"a finite number > 0 and <= {high:g}" if high < math.inf else "a finite number > 0"
            elif math.isfinite(low) and math.isfinite(high):
                wanted = f"a finite number in [{low:g}, {high:g}]"
            elif math.isfinite(low) or math.isfinite(high):  # one bound: "in [0, inf], got inf" (review)
                wanted = f"a finite number >= {low:g}" if math.isfinite(low) else f"a finite number <= {high:g}"
            else:
                wanted = "a finite number"
            raise self.error(f"{self.where}.{key} must be {wanted}, got {value!r}")
        return float(value)

    def count(self, key: str, default=None, low: int = 1) -> int:
        value = self.raw(key, default, required=default is None)
        if not is_whole_number(value, low):
            raise self.error(f"{self.where}.{key} must be an integer >= {low}, got {value!r}")
        return value

    def numbers(self, key: str, length: int, default=None) -> tuple[float, ...]:
        value = self.raw(key, default, required=default is None)
        if not (isinstance(value, (list, tuple)) and len(value) == length and all(is_number(v) for v in value)):
            raise self.error(f"{self.where}.{key} must be a list of {length} numbers, got {value!r}")
        return tuple(float(v) for v in value)

    def span(self, key: str, default=None, low: float = 0.0) -> tuple[float, float]:
        """[min, max] with low <= min <= max; a single number means min = max."""
        value = self.raw(key, default, required=default is None)
        if is_number(value):
            value = [value, value]
        if not (isinstance(value, (list, tuple)) and len(value) == 2 and all(is_number(v) for v in value)
                and low <= value[0] <= value[1]):
            raise self.error(f"{self.where}.{key} must be [min, max] with {low} <= min <= max, got {value!r}")
        return float(value[0]), float(value[1])

    def finish(self) -> None:
        unknown = sorted(set(self.node) - self._used, key=repr)  # keys of mixed types (1, 'zz') do not compare
        if unknown:
            raise self.error(f"{self.where}: unknown key(s) {unknown}")
