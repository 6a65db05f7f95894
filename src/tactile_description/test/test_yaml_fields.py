"""The one YAML file loader of the stack (sensor descriptions and scenes): YAML 1.2 floats, clear file errors."""

import math

import pytest
import yaml

from tactile_description.yaml_fields import YamlFields, YamlLoader, load_yaml_file


@pytest.mark.parametrize("text, value", [
    ("5e-1", 0.5), ("1e3", 1000.0), ("1e-3", 0.001), ("1E+3", 1000.0), ("-2e2", -200.0), ("1e308", 1e308),
    ("1.5e3", 1500.0), (".5e1", 5.0), ("1.5", 1.5), ("5.", 5.0), (".inf", math.inf), ("-.inf", -math.inf),
    ("1_000.5", 1000.5),
])
def test_yaml_12_floats_are_floats(tmp_path, text, value):
    path = tmp_path / "f.yaml"
    path.write_text(f"v: {text}\n")
    loaded = load_yaml_file(path, "test file")["v"]
    assert type(loaded) is float and loaded == value


def test_nan_stays_a_float():
    assert math.isnan(yaml.load("v: .nan", Loader=YamlLoader)["v"])


@pytest.mark.parametrize("text, value", [
    ("10", 10), ("-3", -3), ("0", 0), ("0x10", 16), ("abc", "abc"), ("1e", "1e"), ("e3", "e3"), ("1e3x", "1e3x"),
    ("'1e3'", "1e3"), ("true", True), ("1.2.3", "1.2.3"),
    # YAML 1.2's integers, not 1.1's: `seed: 012` was the octal 10, `frames: 1:30` the base-60 number 90
    ("012", 12), ("-012", -12), ("+7", 7), ("1:30", "1:30"), ("0o12", 10), ("0x1f", 31), ("10_000", 10000),
    ("0b101", "0b101"), ("0o", "0o"), ("0x_", "0x_"), ("0o8", "0o8"), ("1:30.5", "1:30.5"), ("-1:30.0", "-1:30.0"),
    ("1.5", 1.5), ("-.5", -0.5), ("+1_000.5", 1000.5), ("-.inf", -math.inf), ("1e3", 1000.0),
])
def test_integers_stay_integers_and_strings_stay_strings(text, value):
    loaded = yaml.load(f"v: {text}", Loader=YamlLoader)["v"]
    assert type(loaded) is type(value) and loaded == value


def test_pyyaml_safe_load_itself_is_left_as_it_is():
    assert yaml.safe_load("v: 1e-3")["v"] == "1e-3"


def test_unreadable_non_utf8_and_non_yaml_files_raise_the_given_error_naming_the_file(tmp_path):
    class Refused(ValueError):
        pass

    with pytest.raises(Refused, match=f"cannot read thing file {tmp_path / 'absent.yaml'}: No such file"):
        load_yaml_file(tmp_path / "absent.yaml", "thing file", Refused)
    with pytest.raises(Refused, match=f"cannot read thing file {tmp_path}: Is a directory"):
        load_yaml_file(tmp_path, "thing file", Refused)
    binary = tmp_path / "binary.yaml"
    binary.write_bytes(b"ok: 1\n" + bytes(range(128, 256)) + bytes(66))  # 200 bytes, not valid UTF-8 at offset 6
    with pytest.raises(Refused, match=f"thing file {binary} is not UTF-8 text \\(bad byte at offset 6\\)"):
        load_yaml_file(binary, "thing file", Refused)
    broken = tmp_path / "broken.yaml"
    broken.write_text("a: [unclosed")
    with pytest.raises(Refused, match=f"thing file {broken} is not valid YAML"):
        load_yaml_file(broken, "thing file", Refused)


def test_nesting_too_deep_for_the_yaml_reader_raises_the_given_error(tmp_path):
    """1 KB of brackets: PyYAML's RecursionError was a traceback (found in review)."""
    deep = tmp_path / "deep.yaml"
    deep.write_text("timeline: " + "[" * 2000 + "]" * 2000 + "\n")
    with pytest.raises(ValueError, match=f"scene {deep} nests its lists or mappings too deeply for a YAML reader"):
        load_yaml_file(deep, "scene", ValueError)


@pytest.mark.parametrize("text", ["0b101", "1:30", "-0x10", "ten"])
def test_an_explicit_int_that_yaml_12_cannot_read_is_refused_naming_the_file_and_line(tmp_path, text):
    """`!!int 0b101` read as YAML 1.1 did (5) until YAML 1.2's integers came; then a ValueError naming no file."""
    tagged = tmp_path / "tagged.yaml"
    tagged.write_text(f"seed: 1\nframes: !!int {text}\n")
    with pytest.raises(ValueError, match=rf"(?s)scene {tagged} is not valid YAML: .*'{text}' is not an integer \(YAML "
                                         r"1.2: decimal, 0o octal or 0x hexadecimal\).*line 2"):
        load_yaml_file(tagged, "scene", ValueError)


@pytest.mark.parametrize("text", ["abc", "_", "1:30", "0x1f"])
def test_an_explicit_float_that_yaml_12_cannot_read_is_refused_naming_the_file_and_line(tmp_path, text):
    """`!!float abc` raised PyYAML's ValueError (`_`: an IndexError) naming neither file nor key, and `!!float 1:30`
    read as YAML 1.1's 90 (review)."""
    tagged = tmp_path / "tagged.yaml"
    tagged.write_text(f"seed: 1\nwidth_mm: !!float {text}\n")
    with pytest.raises(ValueError, match=rf"(?s)sensor description {tagged} is not valid YAML: .*'{text}' is not a "
                                         r"number \(YAML 1.2: e.g. 1.5, 1e-3, .inf\).*line 2"):
        load_yaml_file(tagged, "sensor description", ValueError)


@pytest.mark.parametrize(("text", "value"),
                         [("12", 12.0), ("-1_000.5", -1000.5), ("1e-3", 0.001), ("-.Inf", -math.inf)])
def test_an_explicit_float_of_yaml_12_is_that_number(tmp_path, text, value):
    tagged = tmp_path / "tagged.yaml"
    tagged.write_text(f"width_mm: !!float {text}\n")
    read = load_yaml_file(tagged, "sensor description", ValueError)["width_mm"]
    assert read == value and isinstance(read, float)


def test_a_file_of_aliases_of_aliases_is_refused_before_anything_walks_it(tmp_path):
    """600 bytes that expand to 10**9 values ("billion laughs"): a check or an error message's repr of them ran out of
    memory (found in review). The walk that refuses it stops at the limit."""
    text = "a: &a [" + ", ".join(["x"] * 10) + "]\n"
    for level, name in enumerate("bcdefghi"):
        text += f"{name}: &{name} [" + ", ".join([f"*{'abcdefghi'[level]}"] * 10) + "]\n"
    laughs = tmp_path / "laughs.yaml"
    laughs.write_text(text)
    with pytest.raises(ValueError, match=f"scene {laughs} expands to more than 1000000 values through its aliases"):
        load_yaml_file(laughs, "scene", ValueError)
    shared = tmp_path / "shared.yaml"  # aliases as a scene uses them: read as before
    shared.write_text("press: &p {x_mm: 1, y_mm: 2}\ntimeline: [*p, *p, {<<: *p, x_mm: 3}]\n")
    assert load_yaml_file(shared, "scene", ValueError)["timeline"][2] == {"x_mm": 3, "y_mm": 2}


def test_unknown_keys_of_mixed_types_are_all_named():
    """sorted() of 1 and 'zz' raised TypeError (found in review)."""
    fields = YamlFields({1: "oops", "zz": "typo", "known": 3}, "scene")
    assert fields.raw("known") == 3
    with pytest.raises(ValueError, match=r"scene: unknown key\(s\) \['zz', 1\]"):
        fields.finish()


def test_a_key_given_twice_in_one_mapping_is_refused_naming_both_lines(tmp_path):
    """PyYAML keeps the last value: a scene's second `seed:` silently replaced the first."""
    scene = tmp_path / "scene.yaml"
    scene.write_text("name: twice\nseed: 1\ncontacts:\n  - {x_mm: 1, x_mm: 2}\n")
    with pytest.raises(ValueError, match=r"(?s)not valid YAML: .*found key 'x_mm' a second time \(first on line 4\)"):
        load_yaml_file(scene, "scene file")
    scene.write_text("name: twice\nseed: 1\nother: {a: 1}\nseed: 2\n")
    with pytest.raises(ValueError, match=r"(?s)found key 'seed' a second time \(first on line 2\).*line 4"):
        load_yaml_file(scene, "scene file")
    scene.write_text("base: &base {a: 1, b: 2}\nderived:\n  <<: *base\n  b: 3\n")  # merge keys may repeat a key
    assert load_yaml_file(scene, "scene file")["derived"] == {"a": 1, "b": 3}
