"""`tactile-fusion`: train, evaluate, recalibrate, export and benchmark the force-distribution model.

    tactile-fusion train --out DIR [--scene paper_grid | --dataset DIR] [--frames N] [--epochs N] ...
    tactile-fusion eval [--model DIR] [--backend onnxruntime|torch] [--precision fp32|int8|fp16]
                        [--scene NAME [--split all|test] | --dataset DIR] [--hard-cases] [--out DIR] [--json]
    tactile-fusion recalibrate --out DIR [--add-camera ID] [--fractions 0.1,0.2,...]
                               [--recalibration-epochs N] [training options]
    tactile-fusion export [--model DIR] [--fit-threshold] [--measure]
    tactile-fusion bench [--model DIR] [--runs N] [--json]

Without --model, eval, export and bench use the shipped model (models/default); without --scene or --dataset,
eval uses the model's test set: the held-out 20 % of the data it was trained on (training.json), for a scene
simulated again from its seed; for the shipped model the default test set, that of the default scene.
A command that fails (a --dataset that is missing, damaged or of another sensor, for one) leaves behind no empty
directory that it created for --out.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import re
import shlex
import sys
import tempfile
from dataclasses import replace
from pathlib import Path

import torch

from tactile_description import SensorConfigError, left_out_components, load_sensor
from tactile_description.command_line import (
    ArgumentParser,
    StopSignal,
    error_exit,
    number_argument,
    one_line,
    stop_signals_raised,
    stops_quietly_on_closed_pipe,
    whole_number_argument,
)
from tactile_fusion.artifacts import (
    METRICS_JSON,
    MODEL_JSON,
    SENSOR_KEY,
    ModelFileError,
    check_model_fits,
    default_model_dir,
    model_components,
    model_threshold,
    read_model_json,
    sensor_changes,
    sensor_changes_text,
    sensor_changes_warning,
    threshold_text,
)
from tactile_fusion.data import DEFAULT_EXTRA_DRAWS, DatasetMismatchError, FrameDataError, load_dataset_frames
from tactile_fusion.inference import BACKENDS, MAX_THREADS, PRECISIONS, InputError, check_backend, load_predictor
from tactile_fusion.metrics import (
    CONTACT_LEVEL_N,
    contact_level_argument,
    contact_metrics,
    contact_table,
    metrics_table,
)
from tactile_fusion.model import FEATURE_ACTIVATIONS, ModelConfig
from tactile_fusion.sources import MIN_BLUR_SIGMA_PX
from tactile_fusion.training import (
    STEP_PRECISIONS,
    CheckpointMismatchError,
    SettingsMismatchError,
    TrainConfig,
    training_device,
)
from tactile_sim import DatasetError, SceneError


def _threads(args) -> None:
    if args.threads is not None:
        torch.set_num_threads(args.threads)


def _conv_channels(args) -> tuple[int, ...]:
    if not args.conv_channels:
        return ModelConfig().conv_channels
    try:
        return tuple(int(c) for c in args.conv_channels.split(","))
    except ValueError:  # int()'s "invalid literal for int() with base 10: 'a'" named no option (walkthrough)
        raise SettingsError(f"--conv-channels must be whole numbers separated by commas, such as "
                            f"{','.join(map(str, ModelConfig().conv_channels))}, got {args.conv_channels!r}") from None


def _model_config(args) -> ModelConfig:
    return ModelConfig(image_size=args.image_size, conv_channels=_conv_channels(args),
                       hidden_features=args.hidden_features, camera_features=args.camera_features,
                       fusion_rank=args.fusion_rank or None, feature_activation=args.feature_activation)


class SettingsError(ValueError):
    """A training or model setting out of its range (the message names it)."""


def _image_size(sensor, args) -> int:
    """The side of the cameras' square output images, which the model takes; SettingsError for other images (a 128 x
    64 output failed in torch's matrix product once the frames were simulated: found in review), or for a side that
    the conv blocks (--conv-channels) cannot halve each (ModelConfig's refusal named neither the file nor the option:
    found by the docs walkthrough)."""
    sizes = {camera.output_size for camera in sensor.cameras}
    size = next(iter(sizes))
    if len(sizes) != 1 or size[0] != size[1]:
        raise SettingsError(f"{sensor.source}: the model takes square camera images of one size, the sensor "
                            f"description's cameras.output is {' and '.join(f'{w} x {h}' for w, h in sorted(sizes))} "
                            "px; make it square (the reference sensor's: 128 x 128)")
    blocks = len(_conv_channels(args))  # a malformed --conv-channels is refused there, naming the option
    if size[0] % 2 ** blocks:
        raise SettingsError(f"{sensor.source}: the cameras' output images, {size[0]} x {size[0]} px, must be a "
                            f"multiple of {2 ** blocks} px: each of the model's {blocks} conv blocks (--conv-channels) "
                            f"halves them; make cameras.output a multiple of {2 ** blocks} (the reference sensor's: "
                            "128 x 128), or give fewer --conv-channels")
    return size[0]


def _setting(check, *args, **kwargs):
    """check(*args, **kwargs), its ValueError (a setting out of range, which the message names) a SettingsError."""
    try:
        return check(*args, **kwargs)
    except ValueError as exc:
        raise SettingsError(str(exc)) from exc


def _settings(args, cameras: int, **train_overrides) -> tuple[ModelConfig, TrainConfig]:
    """The model and training settings of `train` and `recalibrate`, checked before any frame is simulated; the batch
    sizes against the fewest cameras a model of the command has (batch normalisation, TrainConfig.check_batch_sizes)."""
    try:
        model_config, train_config = _model_config(args), replace(_train_config(args), **train_overrides)
        train_config.check_batch_sizes(cameras)
        training_device(train_config.device)
    except ValueError as exc:
        raise SettingsError(_named_by_option(str(exc), args)) from exc
    return model_config, train_config


#: The command-line option of each TrainConfig field whose option is not named after it.
OPTION_OF_FIELD = {"max_epochs": "--epochs"}


def _option_of(field: str, args) -> str | None:
    """The command-line option that sets TrainConfig or ModelConfig `field`: where the parsed arguments hold one of its
    name (--batch-size), or OPTION_OF_FIELD's; None for a field without one (image_size, from the sensor
    description)."""
    if field in OPTION_OF_FIELD:
        return OPTION_OF_FIELD[field]
    return "--" + field.replace("_", "-") if field in vars(args) and field != "image_size" else None


def _named_by_option(message: str, args) -> str:
    """A TrainConfig or ModelConfig refusal naming the command-line option, not the field ("TrainConfig.max_epochs
    must be ..." for --epochs 0; walkthrough)."""
    return re.sub(r"(?:TrainConfig\.|ModelConfig: )(\w+)", lambda match: _option_of(match[1], args) or match[0],
                  message)


def _fractions(text: str) -> list[float]:
    """--fractions: comma-separated data fractions in (0, 1], checked before the base model trains for minutes."""
    from tactile_fusion.recalibration import checked_fractions

    try:
        fractions = checked_fractions(text.split(","))
    except ValueError as exc:
        raise SettingsError(f"--fractions must be comma-separated numbers in (0, 1], got {text!r}") from exc
    if len(set(fractions)) < 2:
        raise SettingsError(f"--fractions must name two different fractions or more (the study fits a trend line "
                            f"through its errors), got {text!r}")
    return fractions


def _train_config(args) -> TrainConfig:
    return TrainConfig(max_epochs=args.epochs, batch_size=args.batch_size, learning_rate=args.learning_rate,
                       end_to_end_dropout=args.end_to_end_dropout, patience=args.patience, seed=args.seed,
                       head_epochs=args.head_epochs,
                       head_batch_size=args.head_batch_size, head_learning_rate=args.head_learning_rate,
                       head_dropout=args.head_dropout, head_noise_sigma=args.head_noise_sigma,
                       head_blur_fraction=args.head_blur_fraction, head_blur_sigma_px=args.head_blur_sigma_px,
                       head_misalign_fraction=args.head_misalign_fraction,
                       head_misalign_shift_px=args.head_misalign_shift_px,
                       head_misalign_rotation_deg=args.head_misalign_rotation_deg, head_cycles=args.head_cycles,
                       head_precision=args.head_precision, device=args.device)


def _further_draws(args, sensor):
    """--head-extra-draws as pipeline.further_draws resolves it, checked before anything trains."""
    from tactile_fusion.pipeline import further_draws

    return _setting(further_draws, sensor, args.scene, args.dataset, args.frames, args.head_extra_draws,
                    progress=not (args.quiet or getattr(args, "json", False)))


def cmd_train(args) -> int:
    from tactile_fusion.pipeline import (
        CHECKPOINTS,
        DEFAULT_SCENE,
        check_fresh,
        check_resumable,
        scene_source,
        train_and_export,
        training_splits,
    )

    (check_resumable if args.resume else check_fresh)(args.out)
    if args.resume and not any(Path(args.out).glob(CHECKPOINTS)):  # a mistyped --out trained afresh unsaid (review)
        print(f"tactile-fusion train: --resume: {args.out} holds no checkpoint: training from scratch",
              file=sys.stderr)
    _threads(args)
    sensor = load_sensor(args.sensor)
    args.image_size = _image_size(sensor, args)
    model_config, train_config = _settings(args, sensor.n_cameras)
    head_extra = _further_draws(args, sensor)
    _output_dir(args.out)  # once the settings are accepted, before the data is simulated and the model trained
    splits = training_splits(sensor, args.scene, args.dataset, args.frames, progress=not args.quiet)
    if not splits["train"].bin_forces_n.any():  # a perfect score on nothing, without a word (walkthrough)
        limited = args.frames is not None
        hint = (" (the default scene's first 120 frames are at rest)" if limited and not args.dataset
                and args.scene == DEFAULT_SCENE else "")
        print(f"tactile-fusion train: warning: the {len(splits['train'])} training frames carry no load{hint}: the "
              "model learns no force, and its test figures say nothing of presses"
              + ("; take more frames (--frames)" if limited else ""), file=sys.stderr)
    # Absolute paths, so that `export` finds the same data from anywhere (installed scenes go by name).
    source = f"dataset {Path(args.dataset).resolve()}" if args.dataset else scene_source(args.scene)
    try:
        metrics = train_and_export(sensor, splits, model_config, train_config, args.out, args.resume,
                                   progress=not args.quiet, threads=args.threads, data_source=source,
                                   head_extra=head_extra)
    except SettingsMismatchError as exc:  # named by the options that set them (--epochs, not max_epochs; review)
        raise CheckpointMismatchError(exc.describe(lambda setting: _option_of(setting, args) or setting)) from exc
    print(metrics_table({f"{splits['test'].scene} test ({b})": m for b, m in metrics["backends"].items()}))
    print(f"model written to {args.out}")
    description = read_model_json(args.out)
    components = model_components(description)
    left_out = left_out_components(components)
    if left_out:
        print(f"it estimates {', '.join(components)} only: the training data has no {', '.join(left_out)}, which "
              "the model outputs as 0")
    threshold = model_threshold(description)
    if threshold is not None:
        print(f"its Fz threshold, chosen on the validation split: {threshold_text(threshold)} (Fz per bin comes out as "
              "max(Fz - threshold, 0))")
    return 0


def _eval_sets(args, sensor, model_dir: Path) -> tuple[list[tuple[str, object]], dict[str, str]]:
    """(name, frames) of each data set to evaluate on: the test split of the model's training data unless --scene
    or --dataset says otherwise (a scene's test split that of the model's when it was trained on that scene), and
    {name: why} of each hard case left out: made for the reference sensor, it may not fit another (the effects
    scene names cameras cam1-cam3); before, one of them ended the whole evaluation (found in review)."""
    from tactile_fusion.pipeline import HARD_CASE_SCENES, held_out_split, scene_frames, scene_source, training_source

    if args.split is not None and not args.scene:
        raise SettingsError("--split applies to --scene only (a --dataset is evaluated whole; without either, eval "
                            "takes the test split of the model's training data)")
    progress = not (args.json or args.quiet)
    if args.dataset:
        sets = [(f"dataset {Path(args.dataset).name}", load_dataset_frames(args.dataset, sensor).first(args.frames))]
    elif args.scene and args.split != "test":
        frames = scene_frames(sensor, args.scene, frames=args.frames, progress=progress)
        sets = [(f"{frames.scene} (all)", frames)]
    elif args.scene and training_source(model_dir) != scene_source(args.scene):
        frames = scene_frames(sensor, args.scene, "test", args.frames, progress)
        sets = [(f"{frames.scene} test split", frames)]
    else:
        test, source, note = held_out_split(model_dir, sensor, "test", args.frames, progress)
        if note:  # on stderr with --json or --quiet: it went unsaid there (review)
            print(f"evaluating on the {source} test split{note}", file=sys.stderr if args.json or args.quiet
                  else sys.stdout)
        sets = [(f"{test.scene} test split", test)]
    skipped = {}
    for name in HARD_CASE_SCENES if args.hard_cases else ():
        try:
            sets.append((name, scene_frames(sensor, name, frames=args.frames, progress=progress)))
        except SceneError as exc:
            skipped[name] = one_line(exc)
    return sets, skipped


def _output_dir(path: str) -> Path:
    """--out: the directory, created if need be and tried with a file, so that one that cannot be written is refused
    before anything is evaluated (SettingsError naming it)."""
    out = Path(path)
    try:
        out.mkdir(parents=True, exist_ok=True)
        tempfile.TemporaryFile(dir=out).close()
    except OSError as exc:
        raise SettingsError(f"--out {path} cannot be written to as a directory ({exc.strerror or exc}: "
                            f"{exc.filename or path}); give a directory that can be created and written to") from exc
    return out


@contextlib.contextmanager
def _new_out_removed_on_failure(path: str | None):
    """Run a command with --out `path` (None: no --out): should it fail, the directories of `path` that did not exist
    before it ran and are empty are removed again: a --dataset refused after --out was created and tried
    (_output_dir) leaves no empty directory behind. An --out that existed stays, and so does one holding what
    the command wrote before it failed (train's checkpoints, to resume from)."""
    new = [] if path is None else [d for d in (Path(path), *Path(path).parents) if not d.exists()]  # deepest first
    try:
        yield
    except BaseException:
        for directory in new:
            with contextlib.suppress(OSError):  # never created, or not empty
                directory.rmdir()
        raise


def cmd_eval(args) -> int:
    from tactile_fusion.artifacts import write_json
    from tactile_fusion.evaluation import evaluate
    from tactile_fusion.plots import grid_bin_size_mm, plot_fz_maps

    _setting(check_backend, args.backend, args.precision)
    if args.out and (Path(args.out) / MODEL_JSON).exists():  # its metrics.json holds what `bench` reports
        raise SettingsError(f"--out {args.out} holds a model ({MODEL_JSON}): eval would replace the model's "
                            f"{METRICS_JSON}; give another directory")
    model_dir = Path(args.model) if args.model else default_model_dir()
    sensor = load_sensor(args.sensor)
    predictor = load_predictor(model_dir, args.backend, args.precision, args.threads)
    check_model_fits(predictor, sensor)
    changes = sensor_changes(predictor.made_for, sensor)
    changed = sensor_changes_warning(changes, sensor)
    if changed:
        print(f"tactile-fusion eval: warning: {changed}", file=sys.stderr)
    out = _output_dir(args.out) if args.out else None
    results, figures = {}, {}
    sets, skipped = _eval_sets(args, sensor, model_dir)
    for name, frames in sets:
        if not frames.bin_forces_n.any():  # the default test split's first 21 frames are at rest (walkthrough)
            print(f"tactile-fusion eval: note: the {len(frames)} frame(s) of {name} carry no load: their figures say "
                  "nothing of presses; take more frames (--frames)", file=sys.stderr)
        metrics, predicted = evaluate(predictor, frames, progress=not (args.json or args.quiet))
        metrics["contact"] = contact_metrics(predicted, frames.bin_forces_n, sensor.grid.bin_centers_m(),
                                             args.contact_level)
        results[name] = metrics
        if out:
            slug = name.replace(" ", "_").replace("/", "_").replace("(", "").replace(")", "")
            figures[name] = f"fz_map_{slug}.png"
            plot_fz_maps(frames.bin_forces_n, predicted, out / figures[name],
                         f"{name}: Fz per bin ({args.backend} {args.precision})",
                         bin_size_mm=grid_bin_size_mm(sensor.grid))
    first = next(iter(results.values()))
    report = {"rmse_bin_n": first["rmse_bin_n"], "rmse_total_n": first["rmse_total_n"],
              "model": str(model_dir), "backend": args.backend, "precision": args.precision,
              "sensor_changes": changes, "data_sets": results,
              "hard_cases_left_out": skipped}
    if out:  # with the figures of this evaluation: those of an earlier one in --out stay beside it (walkthrough)
        write_json(out / "metrics.json", {**report, "figures": figures})
    if args.json:
        print(json.dumps(report))
    else:
        print(metrics_table(results))
        print()
        print(contact_table({name: m["contact"] for name, m in results.items()}))
    for name, why in skipped.items():  # on stderr: with --json too, beside the report's hard_cases_left_out
        print(f"tactile-fusion eval: hard case {name} left out: this sensor cannot play it ({why})", file=sys.stderr)
    return 0


def cmd_recalibrate(args) -> int:
    from tactile_fusion.study import camera_to_add, run_recalibration_study

    _threads(args)
    sensor = load_sensor(args.sensor)
    added_camera = _setting(camera_to_add, sensor, args.add_camera)
    args.image_size = _image_size(sensor, args)
    # The base model, without the added camera, has the fewest cameras.
    model_config, train_config = _settings(args, sensor.n_cameras - 1, recalibration_epochs=args.recalibration_epochs)
    fractions = _fractions(args.fractions)
    head_extra = _further_draws(args, sensor)
    out = _output_dir(args.out)  # once the settings are accepted: the study writes there only at its end
    report = run_recalibration_study(sensor, args.scene, args.dataset, args.frames, added_camera, fractions,
                                     model_config, train_config, out, progress=not (args.json or args.quiet),
                                     head_extra=head_extra)
    print(json.dumps(report) if args.json else recalibration_text(report, args.out))
    return 0


def recalibration_text(report: dict, out: str) -> str:
    """The table and the summary line `recalibrate` prints of its study's report. Fractions to six digits: 0.001
    and 0.004 were both "0 %", one row in place of two; a recalibration slower than full training was "0.7x faster";
    the base model's row was in the JSON only (walkthrough)."""
    table = metrics_table({f"{report['base_cameras']} cameras (before recalibration)":
                           report["base_training"]["metrics"], "full training": report["full_training"]["metrics"]}
                          | {f"recalibrated {100 * r['fraction']:g} %": r["metrics"]
                             for r in report["recalibration"]})
    speedup = report["speedup"]
    factor = speedup["factor"]
    return (f"{table}\nfull training {report['full_training']['wall_time_s']:.1f} s, recalibration with "
            f"{100 * speedup['fraction']:g} % of the data {report['recalibration'][-1]['wall_time_s']:.1f} s: "
            + (f"{factor:.1f}x faster" if factor >= 1 else f"{1 / factor:.1f}x slower") + f"; written to {out}")


def cmd_export(args) -> int:
    from tactile_fusion.pipeline import (
        checked_model,
        export_model_dir,
        export_with_fitted_threshold,
        held_out_split,
        measure_model_dir,
    )

    _threads(args)
    model_dir = Path(args.model) if args.model else default_model_dir()
    sensor = load_sensor(args.sensor)
    checked_model(model_dir, sensor)  # a model of another sensor is refused before any frame is simulated
    changes = sensor_changes(read_model_json(model_dir).get(SENSOR_KEY), sensor)
    if changes and (args.measure or args.fit_threshold):  # they would rewrite the model's records with them
        raise ModelFileError(f"{sensor_changes_text(changes, sensor)}: --measure and --fit-threshold simulate its "
                             "training scene again, which with this description is not the data it was trained on; "
                             "give the description it was trained with (--sensor FILE)")
    # Training data that cannot be read is refused before anything in the directory is rewritten.
    test_split = held_out_split(model_dir, sensor, "test") if args.measure else None
    if args.fit_threshold:
        val, source, note = held_out_split(model_dir, sensor, "val")
        report, paths = export_with_fitted_threshold(model_dir, sensor, val)
        threshold = report["fz_threshold_n"]
        chosen = "none (no candidate beats none)" if threshold is None else threshold_text(threshold)
        print(f"Fz threshold chosen on the validation split of {source}{note}: {chosen}")
    else:
        paths = export_model_dir(model_dir, sensor)
    for precision, path in paths.items():
        print(f"{precision}: {path}")
    if test_split is not None:
        metrics, measured_on = measure_model_dir(model_dir, sensor, test_split, args.threads)
        print(metrics_table({f"{metrics['data']['scene']} test ({b})": m for b, m in metrics["backends"].items()}))
        print(f"figures of {measured_on} written to {model_dir / METRICS_JSON}")
    return 0


def cmd_bench(args) -> int:
    from tactile_fusion.bench import benchmark

    report = benchmark(args.model, runs=args.runs, threads=args.threads, sensor=load_sensor(args.sensor))
    if args.json:
        print(json.dumps(report))
    else:
        split_frames = max((e["accuracy"]["frames"] or 0 for e in report["backends"].values() if e["accuracy"]),
                           default=0)
        for name, entry in report["backends"].items():
            accuracy = entry["accuracy"]
            fewer = accuracy and accuracy["frames"] is not None and accuracy["frames"] != split_frames
            part = f" ({accuracy['frames']} of its frames)" if fewer else ""
            error = (f"  test split{part} Fz RMSE {1e3 * accuracy['rmse_bin_fz_n']:.2f} mN per bin, "
                     f"{1e3 * accuracy['rmse_total_fz_n']:.0f} mN total" if accuracy else "")
            if name in report["accuracy_stale"]:
                model = f" --model {shlex.quote(str(args.model))}" if args.model else ""
                error = (f"  (accuracy unknown: metrics.json has no figures of this file as it is now; measure it "
                         f"with tactile-fusion eval{model} --backend {entry['backend']} --precision "
                         f"{entry['precision']}, or re-export and record every backend's figures with "
                         f"tactile-fusion export{model} --measure)")
            print(f"{name:<20} {entry['ms_per_frame']:8.3f} ms/frame  (p90 {entry['p90_ms']:.3f}, "
                  f"x{entry['ratio_to_baseline']:.2f} of {report['baseline']}){error}")
    for name, why in report["failed"].items():
        print(f"tactile-fusion bench: {name} left out: {why}", file=sys.stderr)
    return 1 if report["failed"] else 0


def named(what: str):
    """An argparse type for an option that names a file or directory: "" is refused. It was taken as no option:
    `eval --dataset ""` evaluated the default test set without a word (found in review)."""
    def parse(text: str) -> str:
        if not text:
            raise argparse.ArgumentTypeError(f"must name {what}, got ''")
        return text
    return parse


#: --learning-rate and --head-learning-rate: Adam moves each weight by up to about the learning rate per step; at 10
#: the weights outgrew float16 and the fp16 graph overflowed, found only once the trained model was measured
#: (walkthrough). TrainConfig takes any rate > 0: the tests train with rates that diverge on purpose.
LEARNING_RATE = number_argument(0.0, None, high=1.0)


def _training_options(parser: argparse.ArgumentParser) -> None:
    model, train = ModelConfig(), TrainConfig()
    data = parser.add_mutually_exclusive_group()
    data.add_argument("--scene", default="paper_grid", type=named("a scene or a YAML file"),
                      help="scene name or YAML file to simulate (default "
                      "%(default)s)")
    data.add_argument("--dataset", type=named("a data set directory"),
                      help="train on a dataset written by `tactile-sim generate` instead")
    parser.add_argument("--frames", type=whole_number_argument(3, "frames", " (a train/val/test split needs 3)"),
                        help="use only the first N frames of the scene or dataset (the default scene's first 120 "
                        "are at rest)")
    parser.add_argument("--epochs", type=int, default=train.max_epochs,
                        help="at most this many end-to-end epochs (default %(default)s, sized for the default scene's "
                        "32340 training frames: scale it for a smaller or larger data set)")
    parser.add_argument("--head-epochs", type=int, default=train.head_epochs,
                        help="then at most this many epochs of the head alone on cached conv features (default "
                        "%(default)s, sized like --epochs; 0: no head phase, no imperfect copy and one least-squares "
                        "fit, whatever --head-cycles says)")
    parser.add_argument("--head-extra-draws", type=whole_number_argument(0, "draws"),
                        help="the head phase and the least-squares fits also learn from this many further draws of "
                        "the scene (its presses drawn again from seed + 1, ...: other positions, depths and noise; "
                        f"default {DEFAULT_EXTRA_DRAWS} for a scene, 0 for a dataset, which cannot be drawn again)")
    parser.add_argument("--head-cycles", type=int, default=train.head_cycles,
                        help="run the head phase and the least-squares fit this many times, each from the one before "
                        "with a new imperfect copy (default %(default)s, see docs/learning.md)")
    parser.add_argument("--batch-size", type=int, default=train.batch_size,
                        help="frames per end-to-end step (default %(default)s)")
    parser.add_argument("--learning-rate", type=LEARNING_RATE, default=train.learning_rate,
                        help="of the end-to-end phase, at its start (a cosine takes it down; default %(default)s)")
    parser.add_argument("--head-batch-size", type=int, default=train.head_batch_size,
                        help="frames per step of the head phase and of recalibration")
    parser.add_argument("--head-learning-rate", type=LEARNING_RATE, default=train.head_learning_rate,
                        help="learning rate of the head phase and of recalibration (default %(default)s)")
    parser.add_argument("--end-to-end-dropout", type=float, default=train.end_to_end_dropout,
                        help="dropout rate of the fully connected layers in the end-to-end phase (default "
                        "%(default)s; the model's, the paper's, is 0.1)")
    parser.add_argument("--head-dropout", type=float, default=train.head_dropout,
                        help="dropout rate of the fully connected layers in the head phase and recalibration (default "
                        "%(default)s)")
    parser.add_argument("--head-noise-sigma", type=float, default=train.head_noise_sigma,
                        help="the head phase also learns from an imperfect copy of the training frames (the "
                        "least-squares fusion fit from the frames alone): Gaussian noise with a standard deviation "
                        "drawn per frame from [0, this] grey levels (default %(default)s) ...")
    parser.add_argument("--head-blur-fraction", type=float, default=train.head_blur_fraction,
                        help="... and defocus blur on this share of them (default %(default)s) ...")
    parser.add_argument("--head-blur-sigma-px", type=float, default=train.head_blur_sigma_px,
                        help=f"... with a sigma drawn from [{MIN_BLUR_SIGMA_PX}, this] pixels (default %(default)s) "
                        "...")
    parser.add_argument("--head-misalign-fraction", type=float, default=train.head_misalign_fraction,
                        help="... and on this share of them one camera knocked askew (default %(default)s) ...")
    parser.add_argument("--head-misalign-shift-px", type=float, default=train.head_misalign_shift_px,
                        help="... shifted by up to this per axis (pixels, default %(default)s) ...")
    parser.add_argument("--head-misalign-rotation-deg", type=float, default=train.head_misalign_rotation_deg,
                        help="... and turned by up to this (degrees, default %(default)s). --head-noise-sigma 0 "
                        "--head-blur-fraction 0 --head-misalign-fraction 0: no copy, the head learns from the frames "
                        "alone (see docs/learning.md)")
    parser.add_argument("--head-precision", choices=list(STEP_PRECISIONS), default=train.head_precision,
                        help="precision of the forward pass in the steps of the head phase and of recalibration "
                        "(default %(default)s: bf16 where the CPU, or the GPU of --device, has bf16 instructions, else "
                        "fp32; see docs/learning.md)")
    parser.add_argument("--device", default=train.device,
                        help="where the gradient steps run: cpu (default) or cuda, cuda:N (a GPU, with a CUDA build of "
                        "torch); the simulation, the caches of the conv trunk's output, the least-squares fits and the "
                        "evaluation run on the CPU (see docs/learning.md)")
    parser.add_argument("--patience", type=int, default=train.patience,
                        help="early stopping patience (epochs, default %(default)s)")
    parser.add_argument("--seed", type=int, default=train.seed, help="of the model's initial weights, the batches, "
                        "dropout and the imperfect copies (0 to 4294967295, default %(default)s)")
    parser.add_argument("--conv-channels", help="channels of the conv blocks, comma separated (default "
                        f"{','.join(map(str, model.conv_channels))})")
    parser.add_argument("--hidden-features", type=int, default=model.hidden_features,
                        help="width of the first fully connected layer (default %(default)s)")
    parser.add_argument("--camera-features", type=int, default=model.camera_features,
                        help="features per camera, the second fully connected layer's width (default %(default)s)")
    parser.add_argument("--fusion-rank", type=whole_number_argument(0, "ranks", " (0: a dense fusion matrix)"),
                        default=model.fusion_rank or 0, help="rank of the fusion layer (default %(default)s: a dense "
                        "fusion matrix)")
    parser.add_argument("--feature-activation", choices=list(FEATURE_ACTIVATIONS), default=model.feature_activation,
                        help="of the fully connected layers (default %(default)s)")
    parser.add_argument("--out", required=True, type=named("a directory"), help="output directory")


def build_parser() -> argparse.ArgumentParser:
    parser = ArgumentParser(prog="tactile-fusion", description=__doc__.split("\n\n")[0])
    sub = parser.add_subparsers(dest="command", required=True)

    def common(p, with_model: bool, threads: int = 1):
        p.add_argument("--sensor", type=named("a sensor description YAML"),
                       help="sensor description YAML (default: the installed config/sensor.yaml)")
        p.add_argument("--threads", type=whole_number_argument(1, "threads", maximum=MAX_THREADS), default=threads,
                       help=f"CPU threads, 1 to {MAX_THREADS} (default %(default)s)")
        p.add_argument("--quiet", action="store_true", help="no progress bars")
        if with_model:
            p.add_argument("--model", type=named("a model directory"), help="model directory (default: the shipped "
                           "model)")

    p = sub.add_parser("train", help="train a model from the simulator or a dataset, export it, evaluate it")
    common(p, False, threads=os.cpu_count() or 1)
    _training_options(p)
    p.add_argument("--resume", action="store_true", help="continue from the checkpoints in --out (refused where --out "
                   "holds a finished model and no checkpoint: leave it out to train that model again from scratch)")
    p.set_defaults(func=cmd_train)

    p = sub.add_parser("eval", help="RMSE per bin and on the total force, per component")
    common(p, True)
    p.add_argument("--backend", choices=list(BACKENDS), default="onnxruntime")
    p.add_argument("--precision", choices=PRECISIONS, default="fp32",
                   help="; ".join(f"{b}: {', '.join(ps)}" for b, ps in BACKENDS.items()) + " (default %(default)s)")
    data = p.add_mutually_exclusive_group()
    data.add_argument("--scene", type=named("a scene or a YAML file"),
                      help="evaluate on this scene (name or YAML file) instead of the test split of the "
                      "model's training data")
    data.add_argument("--dataset", type=named("a data set directory"),
                      help="evaluate on every frame of this dataset (the first N with --frames; "
                      "--split does not apply)")
    p.add_argument("--split", choices=["all", "test"],
                   help="with --scene only: every frame (the default), or its held-out 20 %% drawn from its seed")
    p.add_argument("--frames", type=whole_number_argument(1, "frames"),
                   help="only the first N frames of each data set: of the test split, the scene (or its --split), "
                   "the dataset and each hard case")
    p.add_argument("--hard-cases", action="store_true", help="also the hard-case scenes the training never saw")
    p.add_argument("--out", type=named("a directory"),
                   help="write metrics.json and Fz map PNGs here (not into a model directory, whose "
                   "metrics.json they would replace)")
    p.add_argument("--json", action="store_true", help="print the metrics as one JSON object")
    p.add_argument("--contact-level", type=contact_level_argument, default=CONTACT_LEVEL_N, metavar="NEWTONS",
                   help="an estimated total Fz from which a frame counts as reporting contact (default %(default)s)")
    p.set_defaults(func=cmd_eval)

    p = sub.add_parser("recalibrate", help="train with all cameras but one, add it by retraining the last layers; "
                       "sweep the data fraction")
    common(p, False, threads=os.cpu_count() or 1)
    _training_options(p)
    p.add_argument("--add-camera", help="the camera to add (default: the sensor's last camera)")
    p.add_argument("--fractions", default="0.1,0.2,0.3,0.4,0.5,0.6,0.7,0.8,0.9,1.0",
                   help="fractions of the training data for recalibration, two different ones or more (default "
                   "%(default)s)")
    p.add_argument("--recalibration-epochs", type=int, default=TrainConfig().recalibration_epochs,
                   help="epochs of the retrained layers, with the head phase's batch size and learning rate "
                   "(default %(default)s)")
    p.add_argument("--json", action="store_true", help="print the report as one JSON object")
    p.set_defaults(func=cmd_recalibrate)

    p = sub.add_parser("export", help="write the ONNX graphs (fp32, fp16, int8) of a model directory")
    common(p, True)
    p.add_argument("--fit-threshold", action="store_true", help="first choose the model's Fz threshold on the "
                   "validation split of its training data, as train does (for models trained before it had one)")
    p.add_argument("--measure", action="store_true", help="then measure every backend and precision on the test "
                   "split of the model's training data and rewrite metrics.json")
    p.set_defaults(func=cmd_export)

    p = sub.add_parser("bench", help="milliseconds per frame of every backend and precision, batch of one, next to "
                       "its test-split accuracy")
    common(p, True)
    p.add_argument("--runs", type=whole_number_argument(1, "runs"), default=300,
                   help="timed runs per backend (default %(default)s)")
    p.add_argument("--json", action="store_true", help="print one JSON object")
    p.set_defaults(func=cmd_bench)
    return parser


@stops_quietly_on_closed_pipe
def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    try:
        with stop_signals_raised(), _new_out_removed_on_failure(getattr(args, "out", None)):
            return args.func(args)
    except (SensorConfigError, ModelFileError, DatasetMismatchError, DatasetError, FrameDataError, SceneError,
            InputError, SettingsError, CheckpointMismatchError, FloatingPointError) as exc:
        return error_exit(f"tactile-fusion {args.command}", exc)
    except StopSignal as stop:  # Ctrl-C or SIGTERM: one line saying what is left, not a traceback
        print(f"tactile-fusion {args.command}: stopped by {stop.named}{_left_behind(args)}", file=sys.stderr)
        return stop.exit_status


def _left_behind(args) -> str:
    """What a stopped command leaves that matters: train's checkpoints, which `--resume` continues from; export's
    graphs, some of them rewritten and the int8 one perhaps deleted (it is removed first, so that no graph of another
    model stays behind; a stop said nothing of it: walkthrough)."""
    from tactile_fusion.pipeline import CHECKPOINTS

    if args.command == "export":
        model = f" --model {shlex.quote(str(args.model))}" if args.model else ""
        return (f"; the ONNX graphs of {args.model or default_model_dir()} may be some new, some old, and the int8 "
                f"one missing: run tactile-fusion export{model} again")
    if args.command != "train" or not any(Path(args.out).glob(CHECKPOINTS)):
        return ""
    return (f"; the checkpoints in {args.out} continue the training where it stopped: run the same command with "
            "--resume")


if __name__ == "__main__":
    sys.exit(main())
