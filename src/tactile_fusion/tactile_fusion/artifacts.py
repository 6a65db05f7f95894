"""A trained model on disk: one directory (the shipped one is src/tactile_fusion/models/default).

  model.json          model config, camera ids, bin grid, force scale, estimated components, Fz threshold (what
                      `load_model` needs), and the sensor it was trained for: its name and physical description
                      (tactile_description.made_for), to name what changed in the description since
  model.pt            the torch state dict, and the model.json fields it was trained with (weights_fields)
  model.onnx          float32 ONNX graph           (export.py)
  model_int8.onnx     int8-quantized ONNX graph    (fusion layer in float)
  model_fp16.onnx     float16 ONNX graph
  training.json       how it was trained: training config, data, split sizes, wall time, history
  metrics.json        test metrics of every backend / precision, with the SHA-256 of the file each one ran
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import math
import os
from collections.abc import Callable, Mapping
from pathlib import Path

import torch

from tactile_description import FORCE_COMPONENTS, SensorDescription
from tactile_description.command_line import one_line
from tactile_description.json_file import read_json
from tactile_description.made_for import changed_fields, changes_text, made_for_problem, physical_fields
from tactile_description.sensor import MAX_BINS
from tactile_description.value_checks import is_whole_number
from tactile_fusion.model import ForceFusionNet, ModelConfig, checked_components, checked_threshold

MODEL_JSON = "model.json"
STATE_DICT = "model.pt"
TRAINING_JSON = "training.json"
METRICS_JSON = "metrics.json"
ONNX_FILES = {"fp32": "model.onnx", "int8": "model_int8.onnx", "fp16": "model_fp16.onnx"}
FORMAT_VERSION = 1


class ModelFileError(ValueError):
    """A model directory that is missing, incomplete or does not fit the sensor description."""


def default_model_dir() -> Path:
    """The shipped model: next to this package in a source checkout, else in the installed share directory."""
    here = Path(__file__).resolve().parent.parent / "models" / "default"
    if (here / MODEL_JSON).exists():
        return here
    try:
        from ament_index_python.packages import get_package_share_directory

        return Path(get_package_share_directory("tactile_fusion")) / "models" / "default"
    except (ImportError, LookupError):
        return here


def backend_file(model_dir: str | Path, backend: str, precision: str) -> Path:
    """The file a backend runs: the state dict for torch, the precision's ONNX graph for ONNX Runtime."""
    return Path(model_dir) / (STATE_DICT if backend == "torch" else ONNX_FILES[precision])


def file_sha256(path: str | Path) -> str:
    """Hex SHA-256 of a file's bytes (metrics.json records it for every file it has figures of)."""
    digest = hashlib.sha256()
    with open(path, "rb") as f:
        for chunk in iter(lambda: f.read(1 << 20), b""):
            digest.update(chunk)
    return digest.hexdigest()


#: The entry of model.json that holds the physical description of the sensor the model was trained for
#: (tactile_description.made_for.physical_fields); models trained before 2026-11-27 lack it.
SENSOR_KEY = "sensor"


def save_model(model: ForceFusionNet, out_dir: str | Path, sensor: SensorDescription | None = None) -> Path:
    """Write model.pt, then model.json, into `out_dir`, each whole or not at all (write_torch_file, write_json).
    `sensor`: the description the model was trained for (None: a model of no sensor's, as in tests)."""
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    write_torch_file(out_dir / STATE_DICT, {**model.state_dict(), WEIGHTS_FIELDS_KEY: weights_fields(model)},
                     "run the command again")
    made_for = {} if sensor is None else {SENSOR_KEY: physical_fields(sensor)}
    write_json(out_dir / MODEL_JSON, {"format_version": FORMAT_VERSION,
                                      "sensor_name": "" if sensor is None else sensor.name,
                                      **model_fields(model), **made_for})
    return out_dir


def sensor_changes(made_for: dict | None, sensor: SensorDescription) -> list[str] | None:
    """The fields of `sensor`'s physical description that differ from `made_for`, the one a model was trained for
    (model.json's SENSOR_KEY, a predictor's `made_for`), such as ["gel_layers[top].youngs_modulus_pa"]; None where
    that is not known. check_model_fits refuses a model of other cameras or bins; this is for what the model cannot
    show, a gel, camera pose or lens edited since training, whose images it never saw."""
    return None if made_for is None else changed_fields(made_for, physical_fields(sensor))


def sensor_changes_text(changes: list[str], sensor: SensorDescription) -> str:
    """`sensor_changes` (not empty) in words."""
    return (f"the sensor description {sensor.source or sensor.name} is not the one the model was trained for: "
            f"{changes_text(changes)} changed since")


def sensor_changes_warning(changes: list[str] | None, sensor: SensorDescription) -> str:
    """What to tell a user who runs a model with `sensor` of its `sensor_changes` ("" where nothing changed or it is
    not known). A warning, not a refusal: the estimates may be off, but the user may know that the change does not
    matter to the images (a value only refined)."""
    if not changes:
        return ""
    return (f"{sensor_changes_text(changes, sensor)}; its estimates may be off: retrain it for this description "
            "(tactile-fusion train --sensor FILE), or use the description it was trained with")


def write_torch_file(path: Path, data: dict, retry: str) -> None:
    """torch.save of `data` into `path` whole or not at all, as replace_file writes; ModelFileError naming the file if
    it cannot be written. torch.save straight onto `path` left it cut short on a full disk, with a traceback from
    torch's writer (found in review).

    Saved to model.partial (PARTIAL_SUFFIX in place of the suffix), not into a buffer: torch names the folder inside
    its zip file after the file, "model" as in the shipped model.pt ("archive" from a buffer), so that `make model`
    still writes the shipped model.pt to the byte."""
    try:
        replace_written(path, path.with_suffix(PARTIAL_SUFFIX), lambda partial: torch.save(data, partial))
    except (OSError, RuntimeError) as exc:  # torch's writer raises a RuntimeError on a full disk
        raise unwritable(path, exc, retry) from exc


def model_fields(model: ForceFusionNet) -> dict:
    """The fields of model.json that `load_model` builds `model` from, as JSON values. An exported graph names them
    in its metadata too (export.py), because it has them built in."""
    return {
        "camera_ids": list(model.camera_ids),
        "rows": model.rows,
        "cols": model.cols,
        "force_scale_n": [float(v) for v in model.force_scale_n],
        "components": list(model.components),
        "fz_threshold_n": model.fz_threshold_n,
        "model_config": model.config.to_dict(),
    }


#: The entry of model.pt that names the model.json fields its weights were trained with (`weights_fields`).
WEIGHTS_FIELDS_KEY = "model_json_fields"


def weights_fields(model: ForceFusionNet) -> dict:
    """What model.pt names of model.json (`load_model` checks it): every field but the Fz threshold, which `export
    --fit-threshold` sets without writing model.pt again. The weights show the grid and the camera count in their
    shapes, but not the cameras' order or names, and the force scale they hold is taken over model.json's."""
    return {key: value for key, value in model_fields(model).items() if key != "fz_threshold_n"}


def mismatched_fields(named: Mapping, fields: dict, where: str) -> list[str]:
    """The fields (model_fields) to which `named`, what a model file names of model.json, gives another value, each
    as "<field> <value named> in <where>, <value> in model.json". What it does not name is not checked (files written
    before they named it)."""
    named = dict(named)
    if isinstance(named.get("model_config"), dict):  # with the defaults of fields that ModelConfig gains later
        with contextlib.suppress(TypeError, KeyError, ValueError):
            named["model_config"] = ModelConfig.from_dict(named["model_config"]).to_dict()
    return [f"{key} {json.dumps(named[key])} in {where}, {json.dumps(value)} in {MODEL_JSON}"
            for key, value in fields.items() if key in named and named[key] != value]


#: What to do about a damaged file of a model directory.
REPLACE_MODEL = "copy the model directory again or retrain it (tactile-fusion train)"


def read_json_object(path: Path, remedy: str) -> dict:
    """The JSON object in the file `path`; ModelFileError naming the file and `remedy` (what to do) if it holds none
    (unreadable, truncated, not JSON, another kind of value)."""
    value = read_json(path, ModelFileError, remedy)
    if not isinstance(value, dict):
        raise ModelFileError(f"{path} holds a JSON {type(value).__name__}, not an object: {remedy}")
    return value


def read_model_json(model_dir: str | Path) -> dict:
    """The model.json of a model directory, checked: its format version, and the fields a model is built from
    (camera ids, bin grid, force scale, model config); ModelFileError naming the file otherwise."""
    path = Path(model_dir) / MODEL_JSON
    if not path.exists():
        missing = f"{MODEL_JSON} is missing" if Path(model_dir).is_dir() else "no such directory"
        raise ModelFileError(f"no model in {model_dir}: {missing}; train one with `tactile-fusion train --out DIR` or "
                             "give the directory of a trained model")
    description = read_json_object(path, REPLACE_MODEL)
    if description.get("format_version") != FORMAT_VERSION:
        raise ModelFileError(f"{path}: format_version {description.get('format_version')!r} is not "
                             f"{FORMAT_VERSION}; retrain the model with this version of tactile_fusion")
    problem = _description_problem(description)
    if problem:
        raise ModelFileError(f"{path}: {problem}; the file is damaged or was edited: {REPLACE_MODEL}")
    return description


def _description_problem(description: dict) -> str:
    """What is wrong with the fields of a model.json that models are built from ("" if nothing)."""
    cameras, scale = description.get("camera_ids"), description.get("force_scale_n")
    if not (isinstance(cameras, list) and cameras and all(isinstance(c, str) for c in cameras)):
        return f"camera_ids must be a non-empty list of camera ids, got {cameras!r}"
    for key in ("rows", "cols"):
        value = description.get(key)
        if not is_whole_number(value):
            return f"{key} must be a whole number >= 1, got {value!r}"
    if description["rows"] * description["cols"] > MAX_BINS:  # 10**6 x 10**6 allocated 48 TB: a traceback
        return (f"rows x cols is {description['rows']} x {description['cols']} bins, more than any sensor description "
                f"takes ({MAX_BINS})")
    if not (isinstance(scale, list) and len(scale) == 3):
        return f"force_scale_n must be a list of 3 numbers, got {scale!r}"
    if SENSOR_KEY in description:
        problem = made_for_problem(description[SENSOR_KEY])
        if problem:
            return f"{SENSOR_KEY} (the sensor description it was trained for): {problem}"
    try:
        ModelConfig.from_dict(description.get("model_config"))
    except (TypeError, KeyError, ValueError) as exc:
        return f"model_config {description.get('model_config')!r} is not a model configuration ({exc!r})"
    try:  # here, not where they are read (model_components, model_threshold), so that the error names the file
        checked_components(description.get("components", FORCE_COMPONENTS))
        checked_threshold(description.get("fz_threshold_n"))
    except ValueError as exc:
        return str(exc)
    return ""


def model_components(description: dict) -> tuple[str, ...]:
    """The force components a model.json says the model estimates; all three for a model saved before models could
    leave one out."""
    try:
        return checked_components(description.get("components", FORCE_COMPONENTS))
    except ValueError as exc:
        raise ModelFileError(f"{MODEL_JSON}: {exc}") from exc


def model_threshold(description: dict) -> float | None:
    """The Fz soft threshold a model.json gives (None for a model saved before models had one)."""
    try:
        return checked_threshold(description.get("fz_threshold_n"))
    except ValueError as exc:
        raise ModelFileError(f"{MODEL_JSON}: {exc}") from exc


def threshold_text(threshold_n: float) -> str:
    """An Fz threshold as the command line and the nodes print it ("3.03 mN")."""
    return f"{1e3 * threshold_n:.3g} mN"


def described_model(model_dir: str | Path, description: dict) -> ForceFusionNet:
    """The untrained model that the model.json `description` of `model_dir` describes (the defaults of older files
    filled in); ModelFileError naming the file if its fields do not make a model."""
    try:
        return ForceFusionNet(ModelConfig.from_dict(description["model_config"]), description["camera_ids"],
                              description["rows"], description["cols"], torch.tensor(description["force_scale_n"]),
                              model_components(description), model_threshold(description))
    except ModelFileError:  # model_components and model_threshold name the file already
        raise
    except (TypeError, ValueError) as exc:
        raise ModelFileError(f"{Path(model_dir) / MODEL_JSON}: {exc}; {REPLACE_MODEL}") from exc


def load_model(model_dir: str | Path) -> ForceFusionNet:
    """The torch model of a model directory, in evaluation mode; ModelFileError naming the file if model.json or
    model.pt cannot be read or do not fit each other."""
    model = described_model(model_dir, read_model_json(model_dir))
    described = model_fields(model)  # before the weights bring their own force scale
    state_path = Path(model_dir) / STATE_DICT
    if not state_path.exists():
        raise ModelFileError(f"{model_dir}: {STATE_DICT} is missing; retrain or re-copy the model directory")

    def unreadable(reason: str) -> ModelFileError:
        return ModelFileError(f"{state_path} cannot be read or does not fit {MODEL_JSON} ({reason}): the file is "
                              f"damaged or of another model; {REPLACE_MODEL}")

    try:
        state = torch.load(state_path, map_location="cpu", weights_only=True)
    except Exception as exc:
        # torch's safe unpickler raises whatever the bytes lead it to (KeyError, IndexError, struct.error, ... for a
        # file of text: found in review; OSError for a directory; a bare EOFError for an empty file): each is a file
        # that cannot be read.
        text = one_line(exc)
        raise unreadable(f"{type(exc).__name__}: {text}" if text else type(exc).__name__) from exc
    try:
        if not isinstance(state, Mapping):  # load_state_dict's TypeError would not say which file
            raise RuntimeError(f"it holds a {type(state).__name__}, not a state dict")
        state = dict(state)
        named = state.pop(WEIGHTS_FIELDS_KEY, {})  # none in a model.pt saved before it named them
        if not isinstance(named, Mapping):
            raise RuntimeError(f"its {WEIGHTS_FIELDS_KEY} is a {type(named).__name__}, not a mapping")
        if "force_scale_n" in state:  # a buffer of every model.pt, older ones included
            named = {"force_scale_n": [float(v) for v in state["force_scale_n"]], **named}
        # Before the weights are loaded: an edit of a field that shapes them (components, grid, model config) is
        # reported as what it is, not as torch's size mismatch.
        mismatches = mismatched_fields(named, described, "the weights")
        if not mismatches:
            model.load_state_dict(state)
    except (RuntimeError, TypeError) as exc:
        raise unreadable(one_line(exc)) from exc
    if mismatches:
        raise ModelFileError(f"{state_path} holds the weights of another model than its {MODEL_JSON} describes "
                             f"({'; '.join(mismatches)}): files of two models are mixed, or {MODEL_JSON} was edited "
                             f"after training; put back the {MODEL_JSON} that came with the weights, or retrain "
                             "(tactile-fusion train)")
    return model.eval()


def check_model_fits(model, sensor: SensorDescription) -> None:
    """Raise ModelFileError unless `model` predicts for exactly the sensor's cameras, bin grid and image size.

    `model`: a ForcePredictor or a ForceFusionNet (anything with camera_ids, rows, cols and image_size). The
    camera order does not matter: inputs are matched to the model by camera id (callers that feed a graph
    directly reorder with FrameSet.select_cameras).
    """
    sizes = {c.output_size for c in sensor.cameras}
    if sorted(model.camera_ids) != sorted(sensor.camera_ids) or \
            (model.rows, model.cols) != (sensor.grid.rows, sensor.grid.cols) or \
            sizes != {(model.image_size, model.image_size)}:
        raise ModelFileError(f"the model is for cameras {list(model.camera_ids)}, {model.rows} x {model.cols} bins "
                             f"and {model.image_size} x {model.image_size} images; the sensor description "
                             f"{sensor.source or sensor.name} has cameras {list(sensor.camera_ids)}, "
                             f"{sensor.grid.rows} x {sensor.grid.cols} bins and "
                             f"{' and '.join(f'{w} x {h}' for w, h in sorted(sizes))} images: use the "
                             "model and the sensor description of the same sensor")


def finite_or_null(value):
    """`value` with every NaN or Inf float, however deep in dicts and lists, as None: JSON has no such numbers, and a
    training that diverged wrote "Infinity" into training.json, which strict JSON readers refuse (found in review)."""
    if isinstance(value, float):
        return value if math.isfinite(value) else None
    if isinstance(value, dict):
        return {key: finite_or_null(item) for key, item in value.items()}
    if isinstance(value, (list, tuple)):
        return [finite_or_null(item) for item in value]
    return value


def write_json(path: str | Path, data: dict) -> None:
    """`data` as indented JSON in `path`, whole or not at all (replace_file); ModelFileError naming the file if it
    cannot be written."""
    path = Path(path)
    try:
        replace_file(path, (json.dumps(finite_or_null(data), indent=2, sort_keys=False, allow_nan=False)
                            + "\n").encode())
    except OSError as exc:
        raise unwritable(path, exc, "run the command again") from exc


def unwritable(path: Path, exc: OSError | RuntimeError, retry: str) -> ModelFileError:
    """The error of a file that cannot be written (a read-only directory, a full disk), naming the file that failed
    (`path` or one written on the way to it) and what to do, ending with `retry`."""
    name = getattr(exc, "filename", None) or path
    reason = getattr(exc, "strerror", None) or one_line(exc)
    return ModelFileError(f"{name} cannot be written ({reason}): make room on the disk or make {path.parent} "
                          f"writable, then {retry}")


#: What a file is written to first, beside itself (`replace_file`).
PARTIAL_SUFFIX = ".partial"


def replace_file(path: Path, data: bytes) -> None:
    """Write `data` to `path` whole or not at all, through a file beside it (PARTIAL_SUFFIX; replace_written). An
    OSError passes (the partial file removed where it can be)."""
    replace_written(path, path.with_name(path.name + PARTIAL_SUFFIX), lambda partial: partial.write_bytes(data))


def replace_written(path: Path, partial: Path, write: Callable[[Path], None]) -> None:
    """`write(partial)`, then `partial` synced to disk and renamed over `path`, so that a write that fails (a full
    disk) or is cut off leaves the file before as it was. What `write` raises passes, the partial file removed where
    it can be."""
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        write(partial)
        with open(partial, "rb") as f:
            os.fsync(f.fileno())
        os.replace(partial, path)
    except BaseException:  # a Ctrl-C or SIGTERM (StopSignal) too: a new --out left holding it would not be removed
        discard(partial)
        raise


def discard(path: Path) -> None:
    """Remove the temporary file `path` if it is there and can be (the error being reported matters more)."""
    with contextlib.suppress(OSError):
        path.unlink(missing_ok=True)
