"""A trained model on disk: one directory (the shipped one is src/tactile_fusion/models/default).

  model.json          model config, camera ids, bin grid, force scale, sensor name (what `load_model` needs)
  model.pt            the torch state dict
  model.onnx          float32 ONNX graph           (export.py)
  model_int8.onnx     int8-quantized ONNX graph    (fusion layer in float)
  model_fp16.onnx     float16 ONNX graph
  training.json       how it was trained: training config, data, split sizes, wall time, history
  metrics.json        test metrics of every backend / precision
"""

from __future__ import annotations

import json
from pathlib import Path

import torch

from tactile_description import SensorDescription
from tactile_fusion.model import ForceFusionNet, ModelConfig

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


def save_model(model: ForceFusionNet, out_dir: str | Path, sensor_name: str = "") -> Path:
    """Write model.json and model.pt into `out_dir`."""
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    description = {
        "format_version": FORMAT_VERSION,
        "sensor_name": sensor_name,
        "camera_ids": list(model.camera_ids),
        "rows": model.rows,
        "cols": model.cols,
        "force_scale_n": [float(v) for v in model.force_scale_n],
        "model_config": model.config.to_dict(),
    }
    write_json(out_dir / MODEL_JSON, description)
    torch.save(model.state_dict(), out_dir / STATE_DICT)
    return out_dir


def read_model_json(model_dir: str | Path) -> dict:
    path = Path(model_dir) / MODEL_JSON
    if not path.exists():
        raise ModelFileError(f"no model in {model_dir}: {MODEL_JSON} is missing; train one with "
                             "`tactile-fusion train --out DIR` or give the directory of a trained model")
    description = json.loads(path.read_text())
    if description.get("format_version") != FORMAT_VERSION:
        raise ModelFileError(f"{path}: format_version {description.get('format_version')} is not "
                             f"{FORMAT_VERSION}; retrain the model with this version of tactile_fusion")
    return description


def load_model(model_dir: str | Path) -> ForceFusionNet:
    """The torch model of a model directory, in evaluation mode."""
    description = read_model_json(model_dir)
    model = ForceFusionNet(ModelConfig.from_dict(description["model_config"]), description["camera_ids"],
                           description["rows"], description["cols"], torch.tensor(description["force_scale_n"]))
    state_path = Path(model_dir) / STATE_DICT
    if not state_path.exists():
        raise ModelFileError(f"{model_dir}: {STATE_DICT} is missing; retrain or re-copy the model directory")
    model.load_state_dict(torch.load(state_path, map_location="cpu", weights_only=True))
    return model.eval()


def check_model_fits_sensor(description: dict, sensor: SensorDescription, model_dir: str | Path) -> None:
    """Raise ModelFileError unless the model's cameras, grid and image size are those of `sensor`."""
    size = description["model_config"]["image_size"]
    expected = (tuple(sensor.camera_ids), sensor.grid.rows, sensor.grid.cols,
                {c.output_size for c in sensor.cameras})
    found = (tuple(description["camera_ids"]), description["rows"], description["cols"], {(size, size)})
    if expected != found:
        raise ModelFileError(f"model {model_dir} was trained for cameras {list(found[0])}, a {found[1]} x {found[2]} "
                             f"grid and {size} x {size} images, but the sensor description "
                             f"{sensor.source or sensor.name} has cameras {list(expected[0])}, a {expected[1]} x "
                             f"{expected[2]} grid and images {sorted(expected[3])}: use a model trained for this "
                             "sensor (tactile-fusion train --sensor ...)")


def write_json(path: str | Path, data: dict) -> None:
    Path(path).write_text(json.dumps(data, indent=2, sort_keys=False) + "\n")
