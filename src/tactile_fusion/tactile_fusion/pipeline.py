"""The workflows behind the command line: get frames, train and export a model directory, evaluate it."""

from __future__ import annotations

import platform
import time
from collections.abc import Iterable
from dataclasses import asdict
from pathlib import Path

import numpy as np
import torch

from tactile_description import SensorDescription
from tactile_description.command_line import stop_signals_ignored
from tactile_description.value_checks import is_whole_number
from tactile_fusion.artifacts import (
    METRICS_JSON,
    MODEL_JSON,
    ONNX_FILES,
    TRAINING_JSON,
    ModelFileError,
    backend_file,
    check_model_fits,
    file_sha256,
    load_model,
    read_json_object,
    read_model_json,
    save_model,
    write_json,
)
from tactile_fusion.data import (
    DEFAULT_EXTRA_DRAWS,
    DatasetMismatchError,
    FrameDataError,
    FrameSet,
    SceneDraws,
    check_finite_targets,
    describe_splits,
    first_frames_split,
    forces_sha256,
    load_dataset_frames,
    simulate_frames,
    simulate_splits,
    split_frames,
)
from tactile_fusion.evaluation import evaluate
from tactile_fusion.export import export_onnx, quantize_int8
from tactile_fusion.fz_threshold import fit_fz_threshold
from tactile_fusion.inference import BACKENDS, load_predictor
from tactile_fusion.model import ForceFusionNet, ModelConfig, estimated_components, force_scale_from_targets
from tactile_fusion.plots import grid_bin_size_mm, plot_fz_maps
from tactile_fusion.sources import ImageSource
from tactile_fusion.training import TrainConfig, TrainResult, build_model, parsed_device, train_phases
from tactile_sim import DatasetError, Scene, SceneError, load_scene

DEFAULT_SCENE = "paper_grid"
#: Scenes the training never sees (config/scenes): `tactile-fusion eval --hard-cases` reports each.
HARD_CASE_SCENES = ("edge_corner", "multi_contact", "shear", "effects")
CHECKPOINTS = "checkpoint_*.pt"
FZ_MAP_PNG = "fz_map.png"
#: The splits that training holds out (whose forces' SHA-256 training.json records, `held_out_split`).
HELD_OUT = ("val", "test")
#: What to do about a damaged training.json.
REPLACE_RECORD = "restore it from a copy of the model directory, or retrain the model (tactile-fusion train)"


def scene_frames(sensor: SensorDescription, scene_name: str, split: str | None = None, frames: int | None = None,
                 progress: bool = False) -> FrameSet:
    """Frames of a scene (installed name or YAML file), simulated.

    split: None for every frame (the first `frames` when given), or "train"/"val"/"test" of the 70/10/20 split
    drawn from the scene's seed over the whole scene (the first `frames` of that split when given).
    """
    scene = load_scene(scene_name, sensor)
    if split is None:
        indices = np.arange(len(scene) if frames is None else min(frames, len(scene)))
    else:
        indices = first_frames_split(len(scene), scene.seed)[split][:frames]
    return simulate_frames(sensor, scene, indices, progress=progress)


def training_splits(sensor: SensorDescription, scene_name: str | None, dataset: str | Path | None,
                    frames: int | None, progress: bool) -> dict[str, FrameSet]:
    """The 70/10/20 split of the training data, drawn from its seed: a written dataset or a scene (its first
    `frames` frames). {"train": ..., "val": ..., "test": ...}."""
    if dataset is not None:
        return split_frames(load_dataset_frames(dataset, sensor), frames)
    scene = load_scene(scene_name or DEFAULT_SCENE, sensor)
    return simulate_splits(sensor, scene, first_frames_split(len(scene), scene.seed, frames), progress)


def further_draws(sensor: SensorDescription, scene_name: str | None, dataset: str | Path | None, frames: int | None,
                  draws: int | None, progress: bool) -> SceneDraws:
    """The further draws of the training scene that the head phase learns from besides the training split
    (`--head-extra-draws`), of its first `frames` frames when given. None: DEFAULT_EXTRA_DRAWS for a scene, none for a
    dataset, which cannot be drawn again (asking for draws of a dataset is an error; SceneDraws refuses a negative
    count)."""
    if dataset is not None:
        if draws:
            raise ValueError(f"--head-extra-draws {draws}: a dataset cannot be drawn again; further draws need a "
                             "scene (--scene), or leave the option out")
        return SceneDraws.none(sensor)
    scene = load_scene(scene_name or DEFAULT_SCENE, sensor)
    if frames is not None:
        scene = scene.limited(min(frames, len(scene)))
    return SceneDraws(sensor, scene, DEFAULT_EXTRA_DRAWS if draws is None else draws, progress=progress)


def train_model(train: FrameSet, val: FrameSet, model_config: ModelConfig, train_config: TrainConfig,
                checkpoint_dir: Path | None, resume: bool, progress: bool, head_extra: Iterable[FrameSet] = (),
                fz_threshold: bool = False) -> tuple[ForceFusionNet, dict]:
    """Train on `train` with early stopping on `val`, the head also on `head_extra` (`further_draws`), ending with the
    Fz threshold if `fz_threshold` (train_phases); returns the model and the training results of each phase.
    Non-finite targets are refused before anything is computed from them (data.FrameDataError)."""
    check_finite_targets(training=train, validation=val)
    scale = force_scale_from_targets(torch.from_numpy(train.bin_forces_n))
    rows, cols = train.bin_forces_n.shape[1:3]
    model = build_model(model_config, train.camera_ids, rows, cols, scale, train_config.seed,
                        estimated_components(train.bin_forces_n))
    return model, train_phases(model, train, val, train_config, checkpoint_dir, resume, progress,
                               head_extra=head_extra, fz_threshold=fz_threshold)


def export_all(model: ForceFusionNet, out_dir: Path) -> dict:
    """Write the fp32, fp16 and int8 ONNX graphs of `model` into `out_dir`; returns {precision: path}."""
    paths = {"fp32": export_onnx(model, out_dir / ONNX_FILES["fp32"], "fp32"),
             "fp16": export_onnx(model, out_dir / ONNX_FILES["fp16"], "fp16")}
    paths["int8"] = quantize_int8(paths["fp32"], out_dir / ONNX_FILES["int8"])
    return paths


#: Test frames that a backend is measured on, where not all of them (spread evenly over the split). PyTorch's
#: float16 convolutions run in a reference kernel on a CPU without float16 arithmetic (this one has no AVX512-FP16):
#: about 10 ms per frame, five times torch fp32, which on the default scene's 9240 test frames took about 100 s of
#: `make model`. ONNX Runtime fp16 runs the same float16 network over every test frame.
MEASURED_FRAMES = {"torch_fp16": 1024}


def measured_frames(key: str, frames: int) -> np.ndarray | None:
    """Indices of the test frames that backend `key` is measured on (`MEASURED_FRAMES`), None for all of them. Spread
    evenly, not the first ones: the split's order follows the scene, and its first frames are not a fair sample."""
    if key not in MEASURED_FRAMES or MEASURED_FRAMES[key] >= frames:
        return None
    return np.unique(np.linspace(0, frames - 1, MEASURED_FRAMES[key]).round().astype(int))


def evaluate_model_dir(model_dir: Path, test: FrameSet, threads: int | None) -> tuple[dict, dict]:
    """Test metrics of every backend and precision (on `measured_frames` of the test split where they are fewer,
    the metrics' "frames"), with each one's largest deviation from torch fp32 (N) on the same frames, the file it
    ran (name and SHA-256) and model.json's SHA-256, so that figures of files that changed since can be told apart,
    and the predictions:
    ({backend_precision: metrics}, {backend_precision: (frames, rows, cols, 3) newtons})."""
    results, predictions, picks = {}, {}, {}
    model_json_sha256 = file_sha256(model_dir / MODEL_JSON)
    for backend, precisions in BACKENDS.items():
        for precision in precisions:
            key = f"{backend}_{precision}"
            picks[key] = measured_frames(key, len(test))
            frames = test if picks[key] is None else test.subset(picks[key])
            metrics, predictions[key] = evaluate(load_predictor(model_dir, backend, precision, threads), frames)
            model_file = backend_file(model_dir, backend, precision)
            results[key] = {**metrics, "model_file": model_file.name, "model_file_sha256": file_sha256(model_file),
                            "model_json_sha256": model_json_sha256}
    for key, predicted in predictions.items():
        reference = predictions["torch_fp32"] if picks[key] is None else predictions["torch_fp32"][picks[key]]
        results[key]["max_abs_deviation_from_torch_fp32_n"] = float(np.abs(predicted - reference).max())
    return results, predictions


def train_and_export(sensor: SensorDescription, splits: dict[str, FrameSet], model_config: ModelConfig,
                     train_config: TrainConfig, out_dir: str | Path, resume: bool = False, progress: bool = True,
                     threads: int | None = None, data_source: str = "", head_extra: SceneDraws | None = None) -> dict:
    """The whole `tactile-fusion train` on the `training_splits` of some data (and the `further_draws` of its scene
    for the head phase): train, save, export, evaluate on the test split, write the JSON files.

    Returns the metrics dict that is written to metrics.json.
    """
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    started = time.perf_counter()
    head_extra = head_extra if head_extra is not None else SceneDraws.none(sensor)
    model, results = train_model(splits["train"], splits["val"], model_config, train_config, out_dir, resume,
                                 progress, head_extra, fz_threshold=True)
    training_wall_s = time.perf_counter() - started
    # A model trained again over another: its records go first, so that a stop or failure while the new files are
    # written leaves none of them beside the new model (eval took the old training.json's test split, a fifth of it
    # training frames of the new model; found by a walkthrough).
    for record in (TRAINING_JSON, METRICS_JSON, FZ_MAP_PNG):
        (out_dir / record).unlink(missing_ok=True)
    save_model(model, out_dir, sensor)
    export_all(model, out_dir)
    metrics = record_test_metrics(out_dir, splits["test"], data_source, sensor, threads)
    write_json(out_dir / TRAINING_JSON, {
        "train_config": asdict(train_config),
        "model_config": model_config.to_dict(),
        "data": {"source": data_source, **describe_splits(splits), "head_extra": head_extra.describe(),
                 "split_targets_sha256": {k: forces_sha256(splits[k].bin_forces_n) for k in HELD_OUT}},
        "sensor": sensor.name,
        "phases": {p: r.to_dict() if isinstance(r, TrainResult) else r for p, r in results.items()},
        "wall_time_s": {"training": training_wall_s,
                        **{p: r.wall_time_s for p, r in results.items() if isinstance(r, TrainResult)}},
        "machine": machine_record(train_config),
    })
    # Training finished: the model files supersede the checkpoints. A stop between two deletions (microseconds) would
    # leave some behind, and the stop's message would offer them to --resume: the stop waits for the last.
    with stop_signals_ignored():
        for checkpoint in out_dir.glob(CHECKPOINTS):
            checkpoint.unlink()
    return metrics


def machine_record(train_config: TrainConfig) -> dict:
    """What trained, as training.json and recalibration.json record it beside their wall times: torch's threads, the
    CPU, torch's version and the GPU of train_config.device (None: the CPU)."""
    device = parsed_device(train_config.device)
    return {"threads": torch.get_num_threads(), "cpu": platform.processor() or platform.machine(),
            "torch": torch.__version__, "gpu": torch.cuda.get_device_name(device) if device.type == "cuda" else None}


def record_test_metrics(model_dir: Path, test: FrameSet, data_source: str, sensor: SensorDescription,
                        threads: int | None) -> dict:
    """Evaluate every backend and precision of a model directory on its test split; write metrics.json and the
    Fz map (fz_map.png, axes in the bins of `sensor`'s grid) of ONNX Runtime fp32. Returns the metrics written."""
    backends, predictions = evaluate_model_dir(model_dir, test, threads)
    metrics = {"data": {"source": data_source, "scene": test.scene, "seed": test.seed, "split": "test",
                        "frames": len(test)},
               "backends": backends}
    metrics.update({k: metrics["backends"]["onnxruntime_fp32"][k] for k in ("rmse_bin_n", "rmse_total_n")})
    write_json(model_dir / METRICS_JSON, metrics)
    plot_fz_maps(test.bin_forces_n, predictions["onnxruntime_fp32"], model_dir / FZ_MAP_PNG,
                 f"{test.scene} test split: Fz per bin", bin_size_mm=grid_bin_size_mm(sensor.grid))
    return metrics


def measure_model_dir(model_dir: str | Path, sensor: SensorDescription, test_split: tuple[FrameSet, str, str],
                      threads: int | None) -> tuple[dict, str]:
    """Measure every backend and precision of a model directory again on `test_split` (`held_out_split`: the
    test split of its training data) and rewrite metrics.json (after an export changed the graphs, their figures
    are stale). Returns the metrics and what they were measured on."""
    model_dir = Path(model_dir)
    test, source, note = test_split
    model = checked_model(model_dir, sensor)
    metrics = record_test_metrics(model_dir, test.select_cameras(model.camera_ids), source, sensor, threads)
    return metrics, f"the test split of {source}{note}"


def checked_model(model_dir: str | Path, sensor: SensorDescription) -> ForceFusionNet:
    """The torch model of a model directory (load_model), after checking that it is `sensor`'s (ModelFileError
    otherwise)."""
    model = load_model(model_dir)
    check_model_fits(model, sensor)
    return model


def export_model_dir(model_dir: str | Path, sensor: SensorDescription) -> dict:
    """Re-export the ONNX graphs of a model directory from its torch state dict; {precision: path}. `sensor` must be
    the model's."""
    return export_all(checked_model(model_dir, sensor), Path(model_dir))


def export_with_fitted_threshold(model_dir: str | Path, sensor: SensorDescription, val: FrameSet
                                 ) -> tuple[dict, dict]:
    """Choose the Fz threshold of a trained model directory on `val` (`held_out_split`: the validation split of its
    training data) as `tactile-fusion train` does, export the graphs with it, then write it into model.json and
    training.json's record; (fit_fz_threshold's report, {precision: path}). For models trained before models had a
    threshold. In this order, a failure on the way (a graph that cannot be written, a Ctrl-C) leaves model.json as it
    was: written first, it named a threshold that the graphs beside it lacked, and eval refused the directory (found in
    review)."""
    model_dir = Path(model_dir)
    model = checked_model(model_dir, sensor)
    report = fit_fz_threshold(model, ImageSource(val.select_cameras(model.camera_ids), model.force_scale_n))
    paths = export_all(model, model_dir)
    description = read_model_json(model_dir)
    description["fz_threshold_n"] = model.fz_threshold_n
    write_json(model_dir / MODEL_JSON, description)  # model.pt stays: the threshold is none of its weights
    record = model_dir / TRAINING_JSON
    if record.exists():
        training = read_json_object(record, REPLACE_RECORD)
        training.setdefault("phases", {})["fz_threshold"] = report
        write_json(record, training)
    return report, paths


def scene_source(scene: str) -> str:
    """How training.json names a scene: "scene NAME" for an installed scene, "scene PATH" (absolute) for a file, so
    that `export` and `eval` find the same data from anywhere."""
    return f"scene {Path(scene).resolve() if Path(scene).is_file() else scene}"


def training_data(model_dir: Path) -> dict | None:
    """The "data" record of the model directory's training.json (what it was trained on, see `data_identity`), None
    without training.json; ModelFileError for a damaged one."""
    record = model_dir / TRAINING_JSON
    if not record.exists():
        return None
    data = read_json_object(record, REPLACE_RECORD).get("data", {})
    if not isinstance(data, dict):
        raise ModelFileError(f"{record}: data must be an object, got {data!r}; {REPLACE_RECORD}")
    return data


def training_source(model_dir: Path) -> str | None:
    """What the model was trained on, as its training.json says ("scene NAME", "scene PATH" or "dataset PATH"); None
    without training.json."""
    data = training_data(model_dir)
    return None if data is None else data.get("source")


def held_out_split(model_dir: Path, sensor: SensorDescription, split: str = "test", frames: int | None = None,
                   progress: bool = False) -> tuple[FrameSet, str, str]:
    """The `split` ("test" or "val") of the data a model was trained on (its first `frames` when given), that data
    ("scene NAME" or "dataset PATH", as training.json says) and a note on where it came from ("" or why the default
    scene).

    The split `train_and_export` made of the data that training.json names (a scene, or a dataset). A model
    directory without training.json gets the default scene's split (and says so). Refused (ModelFileError), rather
    than silently measured on other data: training data that cannot be found, and data that is no longer what
    training.json records: another scene name or seed, fewer frames than were trained on (the split of another
    frame count draws other frames, training frames among them), or for a dataset other forces in the split than
    were held out (their SHA-256, where training.json has it). A scene simulated again is compared by name, seed and
    frame count alone: its forces may differ in the last bits on another CPU.
    """
    record = model_dir / TRAINING_JSON
    data = training_data(model_dir)
    note = "" if data is not None else f" (the model directory has no {TRAINING_JSON})"
    data = data if data is not None else {"source": f"scene {DEFAULT_SCENE}"}
    data_name, source = _read_training_data(record, data, sensor, split)
    picks = _held_out_picks(record, data, data_name, source, split)[:frames]
    held_out = source.subset(picks) if isinstance(source, FrameSet) else simulate_frames(sensor, source, picks,
                                                                                         progress=progress)
    return held_out, data_name, note


def _read_training_data(record: Path, data: dict, sensor: SensorDescription, split: str
                        ) -> tuple[str, FrameSet | Scene]:
    """The training data that training.json (`record`, its "data" `data`) names, as "scene NAME" or "dataset PATH",
    and the frames of that dataset or the scene to simulate."""
    kind, _, name = str(data.get("source", "")).partition(" ")
    if kind not in ("dataset", "scene"):
        raise ModelFileError(f"{record} names no training data (data.source {data.get('source')!r})")
    try:
        return f"{kind} {name}", load_dataset_frames(name, sensor) if kind == "dataset" else load_scene(name, sensor)
    except (OSError, SceneError, DatasetError, DatasetMismatchError, FrameDataError) as exc:
        raise ModelFileError(f"{record} says the model was trained on {kind} {name}, which cannot be read here "
                             f"({exc}); its {split} split is needed") from exc


def _held_out_picks(record: Path, data: dict, data_name: str, source: FrameSet | Scene, split: str) -> np.ndarray:
    """The frame indices of `split` of `source` (a dataset's FrameSet or a Scene) as training drew them, after checking
    that `source` is what training.json (`record`, its "data" `data`) says the model was trained on."""
    dataset = isinstance(source, FrameSet)
    found = {"scene": source.scene if dataset else source.name, "seed": source.seed}
    differ = [f"{key} {data[key]!r} (now {found[key]!r})" for key in found if data.get(key, found[key]) != found[key]]
    trained = data.get("frames", len(source))
    if not is_whole_number(trained) or trained > len(source):
        differ.append(f"frames {trained!r} (now {len(source)})")
    if not differ:
        picks = first_frames_split(len(source), source.seed, trained)[split]
        digests = data.get("split_targets_sha256", {})
        if not isinstance(digests, dict):
            raise ModelFileError(f"{record}: data.split_targets_sha256 must be an object (the SHA-256 of each "
                                 f"split's forces), got {digests!r}; {REPLACE_RECORD}")
        recorded = digests.get(split) if dataset else None
        if recorded is None or forces_sha256(source.bin_forces_n[picks]) == recorded:
            return picks
        differ.append(f"other forces in its {split} split")
    raise ModelFileError(f"{record} says the model was trained on {data_name} with {', '.join(differ)}: its {split} "
                         "split drawn now would not be the frames held out from training (it could hold training "
                         "frames). Put that data back as the model was trained on it (e.g. regenerate the dataset with "
                         "the same scene, seed and frame count), evaluate on other data explicitly (eval --scene or "
                         "--dataset), or retrain the model on the data as it is now")


def check_fresh(out_dir: str | Path) -> None:
    """Refuse to train from scratch in a directory that holds the checkpoints of an interrupted training
    (ModelFileError): the new training overwrote the end-to-end checkpoint without a word and left the head phases'
    beside it, of the other training, which a later --resume then refused (found by a walkthrough)."""
    checkpoints = sorted(p.name for p in Path(out_dir).glob(CHECKPOINTS))
    if checkpoints:
        raise ModelFileError(f"{out_dir} holds the checkpoints of an interrupted training ({', '.join(checkpoints)}): "
                             "continue it with --resume, delete them to train from scratch, or choose another --out")


def check_resumable(out_dir: str | Path) -> None:
    """Refuse to resume training in a model directory whose training finished (ModelFileError): it holds a model and
    no checkpoint (they are deleted when training completes), and resuming there would train a new model from scratch
    over the finished one. A directory with checkpoints resumes from them; a new or empty one starts afresh."""
    out_dir = Path(out_dir)
    if (out_dir / MODEL_JSON).exists() and not any(out_dir.glob(CHECKPOINTS)):
        raise ModelFileError(f"--resume: {out_dir} holds a finished model ({MODEL_JSON}) and no checkpoint to resume "
                             "from (training deletes them when it completes): leave out --resume to train it again "
                             "from scratch, which overwrites it, or choose another --out")
