"""`tactile-fusion` through real subprocesses, with a tiny network and a few simulated frames."""

import json
import os
import re
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import torch

from tactile_fusion.artifacts import (
    METRICS_JSON,
    MODEL_JSON,
    ONNX_FILES,
    PARTIAL_SUFFIX,
    STATE_DICT,
    TRAINING_JSON,
    default_model_dir,
    file_sha256,
)
from tactile_fusion.bench import benchmark
from tactile_fusion.training import TrainConfig

CONFIG = Path(__file__).resolve().parents[3] / "config"
TINY = ["--conv-channels", "2,2,2,2", "--hidden-features", "8", "--camera-features", "8", "--fusion-rank", "4",
        "--quiet"]


def run(*args, check=True, cwd=None):
    result = subprocess.run([sys.executable, "-m", "tactile_fusion.cli", *args], capture_output=True, text=True,
                            timeout=300, env=os.environ | {"PYTHONWARNINGS": "ignore"}, cwd=cwd)
    if check and result.returncode != 0:
        raise AssertionError(f"tactile-fusion {' '.join(args)} failed ({result.returncode}):\n{result.stderr}")
    return result


@pytest.fixture(scope="module")
def tiny_model(tmp_path_factory):
    out = tmp_path_factory.mktemp("tiny_model")
    result = run("train", "--frames", "60", "--epochs", "1", "--head-epochs", "1", "--out", str(out), *TINY)
    return out, result


def test_train_writes_a_complete_model_directory(tiny_model):
    out, result = tiny_model
    for name in (MODEL_JSON, STATE_DICT, TRAINING_JSON, METRICS_JSON, *ONNX_FILES.values()):
        assert (out / name).is_file(), name
    assert not list(out.glob("checkpoint_*.pt"))
    # The default scene's first 60 frames are at rest: no force to learn at all, so the model keeps all three, and
    # train says so (it wrote a model that scored 0.000 everywhere without a word; walkthrough).
    assert ("tactile-fusion train: warning: the 42 training frames carry no load (the default scene's first 120 frames "
            "are at rest)") in result.stderr
    assert json.loads((out / MODEL_JSON).read_text())["components"] == ["fx", "fy", "fz"]
    training = json.loads((out / TRAINING_JSON).read_text())
    assert training["data"]["split_sizes"] == {"train": 42, "val": 6, "test": 12}
    assert training["train_config"]["device"] == "cpu" and training["machine"]["gpu"] is None  # the default
    # The head also learnt from three further draws of those 60 frames (the default for a scene).
    seed = training["data"]["seed"]
    assert training["data"]["head_extra"] == {"draws": 3, "scene": "paper_grid",
                                              "seeds": [seed + 1, seed + 2, seed + 3], "frames": 180}
    cycles = [""] + [f"_{c}" for c in range(2, TrainConfig().head_cycles + 1)]  # the default head cycles
    assert set(training["phases"]) == {"end_to_end", *(f"{p}{c}" for c in cycles for p in ("head", "fusion_fit")),
                                       "fz_threshold", "fusion_refit"}
    # The Fz threshold the last step chose on the validation split is the model's.
    threshold = training["phases"]["fz_threshold"]
    assert json.loads((out / MODEL_JSON).read_text())["fz_threshold_n"] == threshold["fz_threshold_n"]
    assert "none" in threshold["val_rmse_bin_fz_n"] and len(threshold["val_rmse_total_fz_n"]) == 32
    assert ("its Fz threshold, chosen on the validation split" in result.stdout) == \
        (threshold["fz_threshold_n"] is not None)
    metrics = json.loads((out / METRICS_JSON).read_text())
    assert set(metrics["backends"]) == {"onnxruntime_fp32", "onnxruntime_int8", "onnxruntime_fp16", "torch_fp32",
                                        "torch_fp16"}
    assert "onnxruntime_fp32" in result.stdout and "model written to" in result.stdout
    assert "it estimates" not in result.stdout


def test_eval_json_has_the_paper_metrics(tiny_model, tmp_path):
    out, _ = tiny_model
    result = run("eval", "--model", str(out), "--frames", "4", "--json", "--out", str(tmp_path))
    report = json.loads(result.stdout)
    for key in ("rmse_bin_n", "rmse_total_n"):
        assert len(report[key]) == 3 and all(v >= 0 for v in report[key])
    assert report["data_sets"]["paper_grid test split"]["frames"] == 4
    contact = report["data_sets"]["paper_grid test split"]["contact"]
    assert contact["contact_level_n"] == 0.01 and len(contact["bands"]) == 5
    assert contact["frames_without_load"] + sum(b["frames"] for b in contact["bands"]) == 4
    written = json.loads((tmp_path / "metrics.json").read_text())
    # the figures of this evaluation, told apart from an earlier one's in the same --out (walkthrough)
    assert written["figures"] == {"paper_grid test split": "fz_map_paper_grid_test_split.png"}
    assert [p.name for p in tmp_path.glob("fz_map_*.png")] == ["fz_map_paper_grid_test_split.png"]
    assert report["sensor_changes"] == [] and "warning" not in result.stderr  # trained for this description
    # The test split's first frames are at rest: all-zero figures that read like a perfect score (docs walkthrough).
    assert "the 4 frame(s) of paper_grid test split carry no load: their figures say nothing of presses" in \
        result.stderr, result.stderr


def test_eval_warns_of_a_sensor_description_edited_since_training(tiny_model, tmp_path):
    out, _ = tiny_model
    softer = tmp_path / "softer.yaml"
    softer.write_text((CONFIG / "sensor.yaml").read_text().replace("youngs_modulus_kpa: 275.4",
                                                                     "youngs_modulus_kpa: 200.0"))
    result = run("eval", "--model", str(out), "--sensor", str(softer), "--frames", "2", "--json")
    assert json.loads(result.stdout)["sensor_changes"] == ["gel_layers[protective_top].youngs_modulus_pa"]
    assert result.stderr.startswith(f"tactile-fusion eval: warning: the sensor description {softer} is not the one "
                                    "the model was trained for: gel_layers[protective_top].youngs_modulus_pa changed "
                                    "since; its estimates may be off"), result.stderr


def test_eval_measures_a_model_on_the_test_split_of_its_own_training_scene(tmp_path):
    """Without --scene, a model trained on another scene than the default is evaluated on that scene's held-out
    frames: those its metrics.json was measured on."""
    out = tmp_path / "model"
    run("train", "--scene", "shear", "--frames", "60", "--epochs", "1", "--head-epochs", "1", "--head-cycles", "1",
        "--threads", "1", "--out", str(out), *TINY)
    report = json.loads(run("eval", "--model", str(out), "--json").stdout)
    assert list(report["data_sets"]) == ["shear test split"]
    recorded = json.loads((out / METRICS_JSON).read_text())["backends"]["onnxruntime_fp32"]
    assert report["data_sets"]["shear test split"]["frames"] == recorded["frames"] == 12
    assert report["rmse_bin_n"] == pytest.approx(recorded["rmse_bin_n"], rel=1e-6)
    assert report["rmse_total_n"] == pytest.approx(recorded["rmse_total_n"], rel=1e-6)
    # Another scene's test split: that of the whole scene, drawn from its seed.
    report = json.loads(run("eval", "--model", str(out), "--scene", "paper_grid", "--split", "test", "--frames", "3",
                            "--json").stdout)
    assert list(report["data_sets"]) == ["paper_grid test split"]
    assert report["data_sets"]["paper_grid test split"]["frames"] == 3


def test_eval_contact_level_and_frames_are_checked_before_anything_runs(tiny_model):
    out, _ = tiny_model
    result = run("eval", "--model", str(out), "--frames", "4", "--contact-level", "-1", check=False)
    assert result.returncode == 2 and "--contact-level: must be a finite number of newtons > 0" in result.stderr
    result = run("eval", "--model", str(out), "--frames", "-4", check=False)
    assert result.returncode == 2 and "--frames: must be a whole number of frames >= 1" in result.stderr
    result = run("eval", "--model", str(out), "--frames", "4", "--split", "test", check=False)
    assert result.returncode == 2 and "--split applies to --scene only" in result.stderr
    # Presses (the shear scene's first four frames), reported from the level asked for.
    report = json.loads(run("eval", "--model", str(out), "--scene", "shear", "--frames", "4", "--contact-level", "0.5",
                            "--json").stdout)
    contact = report["data_sets"]["shear (all)"]["contact"]
    assert contact["contact_level_n"] == 0.5 and contact["frames_without_load"] == 0
    assert sum(band["frames"] for band in contact["bands"]) == 4
    result = run("eval", "--model", str(out), "--scene", "shear", "--frames", "4", "--contact-level", "0.5", "--quiet")
    assert "estimated total Fz >= 500 mN" in result.stdout and "false contacts" in result.stdout


def test_eval_prints_a_table_for_a_scene_and_each_precision(tiny_model):
    out, _ = tiny_model
    result = run("eval", "--model", str(out), "--scene", "edge_corner", "--frames", "3", "--precision", "int8",
                 "--quiet")
    assert "edge_corner (all)" in result.stdout and "bin Fz mN" in result.stdout


def test_the_benchmark_needs_a_whole_number_of_runs():
    for runs in (0, 2.5):
        with pytest.raises(ValueError, match=f"benchmark: runs must be a whole number >= 1, got {runs}"):
            benchmark(runs=runs)


def test_bench_json_reports_each_backend_and_precision(tiny_model):
    out, _ = tiny_model
    report = json.loads(run("bench", "--model", str(out), "--runs", "5", "--json").stdout)
    assert set(report["backends"]) == {"onnxruntime_fp32", "onnxruntime_int8", "onnxruntime_fp16", "torch_fp32",
                                       "torch_fp16"}
    assert all(entry["ms_per_frame"] > 0 for entry in report["backends"].values())
    assert report["backends"]["onnxruntime_fp32"]["ratio_to_baseline"] == 1.0
    assert report["cameras"] == 4 and report["batch"] == 1 and report["failed"] == {}
    trained = json.loads((out / METRICS_JSON).read_text())["backends"]
    for name, entry in report["backends"].items():  # the accuracy the training measured, next to the speed
        assert entry["accuracy"]["rmse_bin_fz_n"] == trained[name]["rmse_bin_n"][2]
        assert entry["accuracy"]["rmse_total_fz_n"] == trained[name]["rmse_total_n"][2]
    assert "mN per bin" in run("bench", "--model", str(out), "--runs", "5").stdout


def test_bench_leaves_out_a_backend_that_cannot_run_and_times_the_others(tiny_model, tmp_path):
    """One graph missing (an export stopped) ended the benchmark of every backend (walkthrough)."""
    out, _ = tiny_model
    partial = tmp_path / "model"
    shutil.copytree(out, partial)
    (partial / ONNX_FILES["int8"]).unlink()
    result = run("bench", "--model", str(partial), "--runs", "5", "--json", check=False)
    report = json.loads(result.stdout)
    assert result.returncode == 1 and set(report["failed"]) == {"onnxruntime_int8"}
    assert f"{partial / ONNX_FILES['int8']} is missing" in report["failed"]["onnxruntime_int8"]
    assert set(report["backends"]) == {"onnxruntime_fp32", "onnxruntime_fp16", "torch_fp32", "torch_fp16"}
    left_out = f"tactile-fusion bench: onnxruntime_int8 left out: {partial / ONNX_FILES['int8']} is missing"
    assert left_out in run("bench", "--model", str(partial), "--runs", "5", check=False).stderr
    (partial / ONNX_FILES["fp32"]).unlink()  # the baseline, to which every ratio is
    result = run("bench", "--model", str(partial), "--runs", "5", check=False)
    assert result.returncode == 2 and "model.onnx is missing" in result.stderr and not result.stdout


def test_a_stop_during_export_says_the_graphs_may_be_incomplete(tiny_model, tmp_path, monkeypatch, capsys,
                                                                 stop_signals_fail_the_test):
    """The int8 graph is removed before it is written again: a stop then left it missing without a word (walkthrough).
    The signal is sent to this process as the int8 graph is quantized."""
    from tactile_fusion import pipeline
    from tactile_fusion.cli import main

    out, _ = tiny_model
    model = tmp_path / "model"
    shutil.copytree(out, model)
    quantize = pipeline.quantize_int8

    def quantize_and_stop(fp32_path, int8_path):
        Path(int8_path).unlink()
        os.kill(os.getpid(), signal.SIGTERM)
        return quantize(fp32_path, int8_path)

    monkeypatch.setattr(pipeline, "quantize_int8", quantize_and_stop)
    assert main(["export", "--model", str(model)]) == 128 + signal.SIGTERM
    assert capsys.readouterr().err.strip().splitlines()[-1] == (
        f"tactile-fusion export: stopped by SIGTERM; the ONNX graphs of {model} may be some new, some old, and the "
        f"int8 one missing: run tactile-fusion export --model {model} again")


def test_bench_of_a_directory_without_a_model_says_so_before_reading_its_metrics(tiny_model, tmp_path, capsys):
    """With metrics.json read first, a directory without model.json ended in a FileNotFoundError (found in review)."""
    out, _ = tiny_model
    (tmp_path / METRICS_JSON).write_text((out / METRICS_JSON).read_text())
    assert refusal(capsys, "bench", "--model", tmp_path).endswith(f"no model in {tmp_path}: model.json is missing; "
                                                                  "train one with `tactile-fusion train --out DIR` or "
                                                                  "give the directory of a trained model")


def test_bench_without_recorded_metrics_reports_speed_only(tiny_model, tmp_path):
    out, _ = tiny_model
    bare = tmp_path / "model"
    shutil.copytree(out, bare)
    (bare / METRICS_JSON).unlink()
    report = json.loads(run("bench", "--model", str(bare), "--runs", "5", "--json").stdout)
    assert report["accuracy_source"] is None
    assert all(e["accuracy"] is None and e["ms_per_frame"] > 0 for e in report["backends"].values())


def test_bench_leaves_out_the_accuracy_of_a_file_that_changed_since_it_was_measured(tiny_model, tmp_path):
    out, _ = tiny_model
    changed = tmp_path / "model"
    shutil.copytree(out, changed)
    shutil.copy(changed / ONNX_FILES["fp32"], changed / ONNX_FILES["int8"])  # a valid graph, not the one measured
    report = json.loads(run("bench", "--model", str(changed), "--runs", "5", "--json").stdout)
    assert report["accuracy_stale"] == ["onnxruntime_int8"]
    assert report["backends"]["onnxruntime_int8"]["accuracy"] is None
    assert report["backends"]["onnxruntime_fp32"]["accuracy"] is not None
    assert (f"accuracy unknown: metrics.json has no figures of this file as it is now; measure it with "
            f"tactile-fusion eval --model {changed} --backend onnxruntime --precision int8, or re-export and record "
            f"every backend's figures with tactile-fusion export --model {changed} --measure)") in run(
                "bench", "--model", str(changed), "--runs", "5").stdout


def test_bench_accuracy_measured_with_another_model_json_is_stale(tiny_model, tmp_path):
    """The torch backend reads its Fz threshold from model.json (export --fit-threshold changes it, not model.pt):
    bench went on reporting the figures measured with the old threshold as the model's."""
    from tactile_fusion.bench import recorded_accuracy

    out, _ = tiny_model
    changed = Path(shutil.copytree(out, tmp_path / "model"))
    accuracy, stale = recorded_accuracy(changed)
    assert stale == [] and "torch_fp32" in accuracy
    _edited_json(changed / MODEL_JSON, lambda d: d.update(fz_threshold_n=0.05))
    accuracy, stale = recorded_accuracy(changed)
    assert accuracy == {} and sorted(stale) == sorted(json.loads((changed / METRICS_JSON).read_text())["backends"])


def test_the_shipped_figures_were_measured_with_the_shipped_model_json():
    from tactile_fusion.bench import recorded_accuracy

    accuracy, stale = recorded_accuracy(default_model_dir())
    assert stale == [] and len(accuracy) == 5


def test_a_backend_measured_on_fewer_test_frames_says_so_and_is_compared_on_those(tiny_model, tmp_path,
                                                                                    monkeypatch):
    from tactile_description.sensor import load_sensor
    from tactile_fusion import pipeline
    from tactile_fusion.evaluation import predict_frames
    from tactile_fusion.inference import load_predictor
    from tactile_fusion.metrics import force_metrics

    out, _ = tiny_model
    measured = tmp_path / "model"
    shutil.copytree(out, measured)
    monkeypatch.setattr(pipeline, "MEASURED_FRAMES", {"torch_fp16": 5})
    test, source, _ = pipeline.held_out_split(measured, load_sensor())
    backends = pipeline.record_test_metrics(measured, test, source, load_sensor(), threads=1)["backends"]
    assert backends["torch_fp16"]["frames"] == 5
    assert {e["frames"] for k, e in backends.items() if k != "torch_fp16"} == {12}
    spread = test.subset([0, 3, 6, 8, 11])  # its figures and its deviation from torch fp32 are those of these frames
    fp16, fp32 = (predict_frames(load_predictor(measured, "torch", p, 1), spread) for p in ("fp16", "fp32"))
    assert backends["torch_fp16"]["rmse_bin_n"] == force_metrics(fp16, spread.bin_forces_n)["rmse_bin_n"]
    assert backends["torch_fp16"]["max_abs_deviation_from_torch_fp32_n"] == float(np.abs(fp16 - fp32).max())
    report = json.loads(run("bench", "--model", str(measured), "--runs", "3", "--json").stdout)
    assert report["backends"]["torch_fp16"]["accuracy"]["frames"] == 5
    text = run("bench", "--model", str(measured), "--runs", "3").stdout
    assert [line for line in text.splitlines() if "(5 of its frames)" in line][0].startswith("torch_fp16")
    assert text.count("of its frames") == 1


def test_export_measure_records_the_figures_of_changed_graphs(tiny_model, tmp_path):
    import torch

    out, _ = tiny_model
    changed = tmp_path / "model"
    shutil.copytree(out, changed)
    weights = torch.load(changed / STATE_DICT)
    weights["fusion.expand.bias"] += 0.5  # another model: every graph exported from it differs
    torch.save(weights, changed / STATE_DICT)
    before = json.loads((changed / METRICS_JSON).read_text())
    run("export", "--model", str(changed), "--quiet")
    stale = json.loads(run("bench", "--model", str(changed), "--runs", "3", "--json").stdout)["accuracy_stale"]
    assert sorted(stale) == sorted(before["backends"])  # exported, not measured: every figure is stale

    result = run("export", "--model", str(changed), "--measure", "--quiet")
    assert f"figures of the test split of scene paper_grid written to {changed / METRICS_JSON}" in result.stdout
    after = json.loads((changed / METRICS_JSON).read_text())
    assert after["data"] == before["data"]  # the same test split: the 12 test frames of the 60 trained on
    assert after["rmse_bin_n"] != before["rmse_bin_n"]
    report = json.loads(run("bench", "--model", str(changed), "--runs", "3", "--json").stdout)
    assert report["accuracy_stale"] == []
    assert report["backends"]["onnxruntime_int8"]["accuracy"]["rmse_bin_fz_n"] == \
        after["backends"]["onnxruntime_int8"]["rmse_bin_n"][2]


def test_export_fit_threshold_gives_a_model_without_one_the_threshold_train_chose(tmp_path):
    """A model trained on presses, its threshold taken away as in a model.json from before thresholds: export
    --fit-threshold chooses the same threshold again (the same network and validation split), writes it into
    model.json and training.json, and the re-exported, re-measured graphs apply it."""
    out = tmp_path / "model"
    run("train", "--scene", "edge_corner", "--frames", "60", "--epochs", "1", "--head-epochs", "1", "--head-cycles",
        "1", "--threads", "1", "--out", str(out), *TINY)
    trained = json.loads((out / MODEL_JSON).read_text())["fz_threshold_n"]
    assert trained is not None  # a briefly trained model answers presses with spurious forces everywhere
    description = json.loads((out / MODEL_JSON).read_text())
    del description["fz_threshold_n"]
    (out / MODEL_JSON).write_text(json.dumps(description))
    training = json.loads((out / TRAINING_JSON).read_text())
    del training["phases"]["fz_threshold"]
    (out / TRAINING_JSON).write_text(json.dumps(training))
    run("export", "--model", str(out), "--measure", "--quiet")
    assert json.loads((out / METRICS_JSON).read_text())["rmse_bin_n"][2] > 0

    weights = file_sha256(out / STATE_DICT)
    result = run("export", "--model", str(out), "--fit-threshold", "--measure", "--threads", "1", "--quiet")
    assert f"Fz threshold chosen on the validation split of scene edge_corner: {1e3 * trained:.3g} mN" in result.stdout
    assert json.loads((out / MODEL_JSON).read_text()) == {**description, "fz_threshold_n": trained}
    assert file_sha256(out / STATE_DICT) == weights  # the threshold is no weight: model.pt is not written again
    assert json.loads((out / TRAINING_JSON).read_text())["phases"]["fz_threshold"]["fz_threshold_n"] == trained
    measured = json.loads((out / METRICS_JSON).read_text())["backends"]
    assert measured["onnxruntime_fp32"]["max_abs_deviation_from_torch_fp32_n"] < 1e-5
    for precision, name in ONNX_FILES.items():
        assert measured[f"onnxruntime_{precision}"]["model_file_sha256"] == file_sha256(out / name), precision

    # A graph that cannot be written leaves model.json and training.json as they were: written first, they named a
    # threshold that the graphs beside them lacked, and eval refused the directory (found in review).
    (out / MODEL_JSON).write_text(json.dumps(description))
    (out / TRAINING_JSON).write_text(json.dumps(training))
    run("export", "--model", str(out), "--quiet")
    before = {f.name: file_sha256(f) for f in out.iterdir()}
    partial = (out / ONNX_FILES["fp32"]).with_name(ONNX_FILES["fp32"] + PARTIAL_SUFFIX)
    partial.symlink_to("/dev/full")
    failed = run("export", "--model", str(out), "--fit-threshold", "--threads", "1", "--quiet", check=False)
    assert failed.returncode == 2 and "cannot be written (No space left on device)" in failed.stderr
    assert {f.name: file_sha256(f) for f in out.iterdir()} == before
    run("eval", "--model", str(out), "--frames", "4", "--quiet")  # still a consistent model directory


def test_export_rewrites_the_graphs_that_were_measured(tiny_model):
    """A re-export writes byte for byte the graphs whose figures metrics.json holds (it needs no data: int8 is
    quantized dynamically)."""
    out, _ = tiny_model
    before = (out / ONNX_FILES["fp32"]).stat().st_mtime_ns
    result = run("export", "--model", str(out), "--quiet")
    assert (out / ONNX_FILES["fp32"]).stat().st_mtime_ns > before
    assert f"int8: {out / ONNX_FILES['int8']}" in result.stdout
    assert not list(out.glob(f"*{PARTIAL_SUFFIX}"))  # each graph written beside its file, then renamed over it
    measured = json.loads((out / METRICS_JSON).read_text())["backends"]
    for precision, name in ONNX_FILES.items():
        assert measured[f"onnxruntime_{precision}"]["model_file"] == name
        assert measured[f"onnxruntime_{precision}"]["model_file_sha256"] == file_sha256(out / name), precision


def test_export_measure_without_a_training_record_measures_the_default_scene_and_says_so(tiny_model, tmp_path):
    out, _ = tiny_model
    bare = tmp_path / "model"
    shutil.copytree(out, bare)
    (bare / TRAINING_JSON).unlink()
    result = run("export", "--model", str(bare), "--measure", "--quiet")
    assert ("figures of the test split of scene paper_grid (the model directory has no training.json) written to "
            f"{bare / METRICS_JSON}") in result.stdout
    assert json.loads((bare / METRICS_JSON).read_text())["data"]["source"] == "scene paper_grid"
    # eval says so too, on stderr where its output is JSON (it went unsaid there; review)
    result = run("eval", "--model", str(bare), "--frames", "30", "--json")
    assert "evaluating on the scene paper_grid test split (the model directory has no training.json)" in \
        result.stderr
    json.loads(result.stdout)


def test_export_measure_refuses_a_model_whose_training_data_is_gone(tiny_model, tmp_path):
    out, _ = tiny_model
    moved = tmp_path / "model"
    shutil.copytree(out, moved)
    training = json.loads((moved / TRAINING_JSON).read_text())
    training["data"]["source"] = f"dataset {tmp_path / 'gone'}"
    (moved / TRAINING_JSON).write_text(json.dumps(training))
    files = [moved / name for name in (METRICS_JSON, *ONNX_FILES.values())]
    written = [f.stat().st_mtime_ns for f in files]  # exports are deterministic: only the time shows a rewrite
    result = run("export", "--model", str(moved), "--measure", "--quiet", check=False)
    assert result.returncode == 2
    assert f"says the model was trained on dataset {tmp_path / 'gone'}, which cannot be read here" in result.stderr
    assert [f.stat().st_mtime_ns for f in files] == written  # refused before anything was rewritten
    run("export", "--model", str(moved), "--quiet")  # without --measure, export needs no data
    assert all(f.stat().st_mtime_ns > t for f, t in zip(files[1:], written[1:], strict=True))


def test_a_model_trained_on_a_dataset_by_relative_path_is_measured_from_anywhere(tmp_path, capsys):
    from tactile_description import load_sensor
    from tactile_fusion.cli import main
    from tactile_fusion.data import split_indices
    from tactile_sim import Simulator, load_scene, write_dataset

    sensor = load_sensor(CONFIG / "sensor.yaml")
    write_dataset(Simulator(sensor), load_scene("paper_grid", sensor), tmp_path / "data", progress=False, frames=40)
    run("train", "--dataset", "data", "--epochs", "1", "--head-epochs", "1", "--out", "model", *TINY, cwd=tmp_path)
    model = tmp_path / "model"
    data = json.loads((model / TRAINING_JSON).read_text())["data"]
    assert data["source"] == f"dataset {tmp_path / 'data'}"
    assert data["head_extra"] == {"draws": 0, "frames": 0}  # a dataset cannot be drawn again
    result = run("export", "--model", str(model), "--measure", "--quiet")
    assert f"figures of the test split of dataset {tmp_path / 'data'} written to" in result.stdout
    measured = json.loads((model / METRICS_JSON).read_text())["backends"]
    assert measured["onnxruntime_int8"]["model_file_sha256"] == file_sha256(model / ONNX_FILES["int8"])

    # Written again with fewer frames, the dataset's split would draw other frames, training frames among them.
    write_dataset(Simulator(sensor), load_scene("paper_grid", sensor), tmp_path / "data", progress=False, frames=30,
                  overwrite=True)
    assert f"says the model was trained on dataset {tmp_path / 'data'} with frames 40 (now 30): its test split" in \
        refusal(capsys, "eval", "--model", model, "--quiet")
    # With more, its first 40 frames are those trained on: the same test split.
    write_dataset(Simulator(sensor), load_scene("paper_grid", sensor), tmp_path / "data", progress=False, frames=50,
                  overwrite=True)
    assert main(["eval", "--model", str(model), "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["data_sets"]["paper_grid test split"]["frames"] == 8
    forces = np.load(tmp_path / "data" / "forces.npy")
    forces[split_indices(40, data["seed"])["test"][3], 0, 0, 2] = 0.01  # a test frame that is not what was held out
    np.save(tmp_path / "data" / "forces.npy", forces)
    assert "with other forces in its test split" in refusal(capsys, "eval", "--model", model, "--quiet")


def test_recalibrate_writes_the_sweep_json_and_plot(tmp_path):
    result = run("recalibrate", "--frames", "60", "--epochs", "1", "--fractions", "0.5,0.25", "--out", str(tmp_path),
                 "--recalibration-epochs", "2", "--json", *TINY)
    report = json.loads(result.stdout)
    assert report["train_config"]["recalibration_epochs"] == 2
    assert report["machine"]["gpu"] is None and report["machine"]["threads"] >= 1  # what the wall times were taken on
    assert [r["epochs_run"] for r in report["recalibration"]] == [2, 2]
    resolved = TrainConfig().recalibration_phase().head_precision  # "auto" as this CPU resolves it
    assert [r["step_precision"] for r in report["recalibration"]] == [resolved, resolved]
    assert report["added_camera"] == "cam3" and report["base_cameras"] == 3
    assert [r["fraction"] for r in report["recalibration"]] == [0.25, 0.5]
    # The speed-up is that of the largest fraction, and says which: here not all the data.
    assert report["speedup"] == {"fraction": 0.5, "factor": pytest.approx(
        report["full_training"]["wall_time_s"] / report["recalibration"][-1]["wall_time_s"])}
    assert (tmp_path / "recalibration.json").is_file() and (tmp_path / "recalibration.png").is_file()


def test_the_recalibration_table_names_every_fraction_and_a_slowdown_as_such():
    from tactile_fusion.cli import recalibration_text

    def metrics(fz_n: float) -> dict:
        return {"frames": 10, "rmse_bin_n": [0.0, 0.0, fz_n], "rmse_total_n": [0.0, 0.0, 10 * fz_n]}

    runs = [{"fraction": f, "wall_time_s": 4.0, "metrics": metrics(0.003)} for f in (0.001, 0.004, 0.1234, 0.1235)]
    report = {"base_cameras": 3, "base_training": {"metrics": metrics(0.004)},
              "full_training": {"wall_time_s": 2.8, "metrics": metrics(0.002)}, "recalibration": runs,
              "speedup": {"fraction": 0.004, "factor": 0.7}}
    text = recalibration_text(report, "OUT")
    for row in ("3 cameras (before recalibration)", "full training", "recalibrated 0.1 %", "recalibrated 0.4 %",
                "recalibrated 12.34 %", "recalibrated 12.35 %"):
        assert row in text, text
    assert text.endswith("recalibration with 0.4 % of the data 4.0 s: 1.4x slower; written to OUT")


def test_the_no_load_warning_of_a_dataset_names_neither_the_default_scene_nor_frames(tmp_path):
    """The warning named the default scene's rest frames and --frames for any data (found in review)."""
    from tactile_description import load_sensor
    from tactile_sim import Simulator, load_scene, write_dataset

    sensor = load_sensor()
    dataset = write_dataset(Simulator(sensor), load_scene("paper_grid", sensor), tmp_path / "rest", progress=False,
                            frames=6)
    result = run("train", "--dataset", str(dataset), "--epochs", "1", "--head-epochs", "1", "--out",
                 str(tmp_path / "model"), *TINY)
    assert ("tactile-fusion train: warning: the 4 training frames carry no load: the model learns no force, and its "
            "test figures say nothing of presses\n") in result.stderr


def test_a_dataset_for_another_sensor_is_refused_with_a_clear_error(tmp_path):
    from tactile_description import load_sensor
    from tactile_sim import Simulator, load_scene, write_dataset

    skin = load_sensor(CONFIG / "skin_3x3.yaml")
    dataset = write_dataset(Simulator(skin), load_scene("paper_grid", skin), tmp_path / "skin", progress=False,
                            frames=3)
    result = run("train", "--dataset", str(dataset), "--out", str(tmp_path / "model"), *TINY, check=False)
    assert result.returncode == 2
    assert "cameras" in result.stderr and "regenerate" in result.stderr


@pytest.mark.parametrize("command, setting, message", [
    ("train", ["--head-dropout", "1.5"], "--head-dropout must be in [0, 1)"),
    ("train", ["--end-to-end-dropout", "1"], "--end-to-end-dropout must be in [0, 1)"),
    # named the field, TrainConfig.max_epochs, not the option (walkthrough)
    ("train", ["--epochs", "0"], "--epochs must be a whole number >= 1"),
    ("train", ["--seed", "-1"], "--seed must be a whole number from 0 to 4294967295, got -1"),
    ("train", ["--head-noise-sigma", "-1"], "--head-noise-sigma must be in [0, 255]"),
    ("train", ["--head-misalign-shift-px", "20"], "--head-misalign-shift-px must be in [0, 16]"),
    ("train", ["--head-misalign-rotation-deg", "50"], "--head-misalign-rotation-deg must be in [0, 45]"),
    ("train", ["--head-extra-draws", "-1"],
     "argument --head-extra-draws: must be a whole number of draws >= 0, got '-1'"),
    ("train", ["--dataset", "data", "--head-extra-draws", "1"],
     "--head-extra-draws 1: a dataset cannot be drawn again"),
    ("train", ["--device", "gpu"], "--device must be 'cpu', 'cuda' or 'cuda:N', got 'gpu'"),
    # a GPU this machine does not have: refused before the frames are simulated, whatever GPUs it has
    ("recalibrate", ["--device", "cuda:99"], "--device 'cuda:99': this "),
    ("recalibrate", ["--recalibration-epochs", "0"], "--recalibration-epochs must be a whole number >= 1"),
    ("recalibrate", ["--fractions", "0.5,x"], "--fractions must be comma-separated numbers in (0, 1]"),
    ("recalibrate", ["--fractions", "0,1"], "--fractions must be comma-separated numbers in (0, 1]"),
    ("recalibrate", ["--fractions", "0.5,0.5"], "--fractions must name two different fractions or more"),
])
def test_a_setting_out_of_range_is_refused_with_a_clear_error(tmp_path, command, setting, message):
    result = run(command, *setting, "--frames", "30", "--out", str(tmp_path / "out"), *TINY, check=False)
    assert result.returncode == 2
    assert f"tactile-fusion {command}: error: {message}" in result.stderr
    assert "Traceback" not in result.stderr and not (tmp_path / "out").exists()


def test_resuming_from_a_checkpoint_of_another_model_is_refused_with_a_clear_error(tmp_path):
    import torch

    out = tmp_path / "model"
    out.mkdir()
    torch.save({"model_config": {"hidden_features": 1}}, out / "checkpoint_end_to_end.pt")
    result = run("train", "--frames", "30", "--epochs", "1", "--head-epochs", "1", "--resume", "--out", str(out),
                 *TINY, check=False)
    assert result.returncode == 2 and "Traceback" not in result.stderr
    assert "tactile-fusion train: error: checkpoint" in result.stderr and "delete the checkpoint" in result.stderr


def test_resume_into_a_directory_without_checkpoints_says_it_trains_from_scratch(tmp_path):
    """A mistyped --out with --resume trained afresh without a word: 30 minutes on the default scene (review)."""
    out = tmp_path / "typo"
    result = run("train", "--frames", "30", "--epochs", "1", "--head-epochs", "1", "--resume", "--out", str(out),
                 *TINY)
    assert f"tactile-fusion train: --resume: {out} holds no checkpoint: training from scratch" in result.stderr
    assert (out / MODEL_JSON).is_file()


def stopped_train(out: Path, stop: signal.Signals, when, *args) -> subprocess.CompletedProcess:
    """`tactile-fusion train --out OUT ARGS`, sent `stop` once `when()` holds (polled; 120 s at most). The child gets
    the default SIGINT disposition, so that Python installs its Ctrl-C handler even where this test runs as a
    background job, which starts with SIGINT ignored."""
    process = subprocess.Popen([sys.executable, "-m", "tactile_fusion.cli", "train", "--out", str(out), *args],
                               stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                               env=os.environ | {"PYTHONWARNINGS": "ignore"},
                               preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    deadline = time.monotonic() + 120
    while not when() and process.poll() is None and time.monotonic() < deadline:
        time.sleep(0.02)
    process.send_signal(stop)
    stdout, stderr = process.communicate(timeout=120)
    return subprocess.CompletedProcess(process.args, process.returncode, stdout, stderr)


def test_a_sigterm_while_train_simulates_ends_it_in_one_line_and_removes_the_new_empty_out(tmp_path):
    """Before: Python died at once, leaving the --out it had created empty and no word of why."""
    out = tmp_path / "new" / "model"
    result = stopped_train(out, signal.SIGTERM, out.exists, *TINY)  # the default scene's 46200 frames: a minute
    assert result.returncode == 128 + signal.SIGTERM, result.stderr
    assert result.stderr.strip().splitlines()[-1] == "tactile-fusion train: stopped by SIGTERM", result.stderr
    assert "Traceback" not in result.stderr and not (tmp_path / "new").exists()


def test_a_stop_while_train_deletes_its_checkpoints_waits_for_the_last(tmp_path, monkeypatch,
                                                                      stop_signals_fail_the_test):
    """The training has finished; a SIGTERM between the deletions of two checkpoints left the others behind, and the
    stop's message offered them to --resume. The signal is sent to this process as the first checkpoint goes."""
    from tactile_fusion.cli import main

    unlink = Path.unlink
    stopped = []

    def unlink_and_stop(path, *args, **kwargs):
        if path.name.startswith("checkpoint_") and not stopped:
            stopped.append(path.name)
            os.kill(os.getpid(), signal.SIGTERM)
        unlink(path, *args, **kwargs)

    monkeypatch.setattr(Path, "unlink", unlink_and_stop)
    out = tmp_path / "model"
    assert main(["train", "--out", str(out), "--frames", "60", "--epochs", "1", "--head-epochs", "1",
                 "--head-cycles", "1", "--threads", "1", *TINY]) == 0
    assert stopped and not list(out.glob("checkpoint_*.pt")) and (out / TRAINING_JSON).is_file()


def test_ctrl_c_during_training_says_the_checkpoints_resume_it(tmp_path):
    """Before: Python's KeyboardInterrupt traceback, with no word that the run can go on."""
    out = tmp_path / "model"
    result = stopped_train(out, signal.SIGINT, lambda: any(out.glob("checkpoint_*.pt")), "--frames", "200",
                           "--epochs", "500", "--patience", "500", *TINY)
    assert result.returncode == 128 + signal.SIGINT, result.stderr
    assert result.stderr.strip().splitlines()[-1] == (
        f"tactile-fusion train: stopped by Ctrl-C; the checkpoints in {out} continue the training where it stopped: "
        "run the same command with --resume"), result.stderr
    checkpoint = torch.load(out / "checkpoint_end_to_end.pt", map_location="cpu", weights_only=False)
    assert "Traceback" not in result.stderr and checkpoint["train_config"]["max_epochs"] == 500
    # Resumed with other settings, it names them by their options: "max_epochs 500 (now 400)" named a setting no
    # option has (review).
    resumed = run("train", "--out", str(out), "--frames", "200", "--epochs", "400", "--patience", "500",
                  "--learning-rate", "0.001", "--resume", *TINY, check=False)
    assert resumed.returncode == 2 and resumed.stderr.strip().endswith(
        f"checkpoint {out / 'checkpoint_end_to_end.pt'} was written with other training settings: --epochs 500 (now "
        "400), --learning-rate 0.002 (now 0.001); resume with the same settings, or delete it and the checkpoints of "
        "the phases after it"), resumed.stderr


def test_hard_cases_another_sensor_cannot_play_are_left_out_saying_why(tmp_path):
    """The effects scene names cameras cam1-cam3: on a sensor with other camera ids `eval --hard-cases` ended with
    that scene's error and evaluated nothing (found in review)."""
    sensor = tmp_path / "renamed.yaml"
    sensor.write_text((CONFIG / "sensor.yaml").read_text().replace("{id: cam", "{id: c"))
    out = tmp_path / "model"
    run("train", "--sensor", str(sensor), "--frames", "30", "--epochs", "1", "--head-epochs", "1", "--out", str(out),
        *TINY)
    report = json.loads(run("eval", "--sensor", str(sensor), "--model", str(out), "--hard-cases", "--frames", "3",
                            "--json").stdout)
    assert set(report["hard_cases_left_out"]) == {"effects"}
    assert "names cameras ['cam1'], but the sensor's cameras are ['c0', 'c1', 'c2', 'c3']" in \
        report["hard_cases_left_out"]["effects"]
    assert {"edge_corner", "multi_contact", "shear"} <= set(report["data_sets"])
    stderr = run("eval", "--sensor", str(sensor), "--model", str(out), "--hard-cases", "--frames", "3").stderr
    assert "tactile-fusion eval: hard case effects left out: this sensor cannot play it (" in stderr


def test_a_model_for_another_sensor_is_refused(tiny_model):
    out, _ = tiny_model
    result = run("eval", "--model", str(out), "--sensor", str(CONFIG / "skin_3x3.yaml"), "--frames", "2",
                 check=False)
    assert result.returncode == 2 and "the model is for cameras" in result.stderr


def refusal(capsys, *args) -> str:
    """The last line that `tactile-fusion ARGS`, run in this process, writes to stderr when it refuses its arguments
    (exit status 2, no traceback): for refusals that come before any frame is simulated."""
    from tactile_fusion.cli import main

    try:
        code = main([str(a) for a in args])
    except SystemExit as exit:  # argparse's own refusals
        code = exit.code
    err = capsys.readouterr().err
    assert code == 2 and "Traceback" not in err, err
    return err.strip().splitlines()[-1]


@pytest.fixture
def one_camera_sensor(tmp_path) -> Path:
    """The reference sensor with its first camera alone."""
    path = tmp_path / "one_camera.yaml"
    path.write_text("".join(line for line in (CONFIG / "sensor.yaml").read_text().splitlines(keepends=True)
                            if not any(f"id: cam{i}" in line for i in (1, 2, 3))))
    return path


@pytest.mark.parametrize("args, message", [
    ("eval --backend torch --precision int8",
     "eval: error: the torch backend runs fp32, fp16, not 'int8'; choose one of those or another backend"),
    ("eval --backend torch --threads -1",
     "eval: error: argument --threads: must be a whole number of threads from 1 to 1024, got '-1'"),
    ("train --threads 0 --out OUT",
     "train: error: argument --threads: must be a whole number of threads from 1 to 1024, got '0'"),
    ("eval --threads 1025 --frames 1",  # unbounded, 100000000 took the memory until the kernel killed the process
     "eval: error: argument --threads: must be a whole number of threads from 1 to 1024, got '1025'"),
    ("recalibrate --threads 1025 --out OUT",
     "recalibrate: error: argument --threads: must be a whole number of threads from 1 to 1024, got '1025'"),
    ("train --frames 2 --out OUT",
     "train: error: argument --frames: must be a whole number of frames >= 3 (a train/val/test split needs 3)"),
    ("bench --runs 0", "bench: error: argument --runs: must be a whole number of runs >= 1, got '0'"),
    # took any description, or none at all, and timed the model (walkthrough)
    ("bench --sensor ONE_CAMERA --runs 1", "bench: error: the model is for cameras ['cam0', 'cam1', 'cam2', 'cam3']"),
    ("bench --sensor OUT --runs 1", "bench: error: cannot read sensor description OUT"),
    ("recalibrate --add-camera nope --out OUT", "recalibrate: error: --add-camera 'nope': expected one of ['cam0'"),
    # "--add-camera 'cam0': expected one of ['cam0'] on a sensor with at least two cameras", no --add-camera given
    ("recalibrate --sensor ONE_CAMERA --out OUT", "recalibrate: error: the recalibration study adds a camera to a "
     "model of the others: the sensor description ONE_CAMERA has one camera, 'cam0'; it needs two or more"),
    ("eval --scene shear --dataset DATA", "eval: error: argument --dataset: not allowed with argument --scene"),
    ("train --scene shear --dataset DATA --out OUT",
     "train: error: argument --dataset: not allowed with argument --scene"),
    ("train --learning-rate inf --out OUT",
     "train: error: argument --learning-rate: must be a finite number in (0, 1], got 'inf'"),
    # the fp16 graph overflowed, found only when the trained model was measured (walkthrough)
    ("train --learning-rate 10 --out OUT", "train: error: argument --learning-rate: must be a finite number in (0, 1], "
     "got '10'"),
    ("recalibrate --head-learning-rate inf --out OUT",
     "recalibrate: error: argument --head-learning-rate: must be a finite number in (0, 1], got 'inf'"),
    ("train --hidden-features 0 --out OUT", "train: error: --hidden-features must be a whole number from 1 "
     "to 16384, got 0"),
    ("train --hidden-features 1000000000 --out OUT", "train: error: --hidden-features must be a whole "
     "number from 1 to 16384, got 1000000000"),
    ("train --conv-channels 4,-8 --out OUT", "train: error: --conv-channels must be one or more whole"),
    # int()'s "invalid literal for int() with base 10: 'a'" (walkthrough)
    ("train --conv-channels 4,a --out OUT", "train: error: --conv-channels must be whole numbers separated by commas, "
     "such as 4,8,16,32,32, got '4,a'"),
    # "must be >= 1 or None", though the option takes 0 for a dense layer (walkthrough)
    ("train --fusion-rank -1 --out OUT", "train: error: argument --fusion-rank: must be a whole number of ranks >= 0 "
     "(0: a dense fusion matrix), got '-1'"),
    ("train --sensor ONE_CAMERA --head-batch-size 1 --out OUT",
     "train: error: --head-batch-size must be >= 2 for a 1-camera model"),
    # failed in torch's matrix product once the frames were simulated (found in review)
    ("train --sensor NOT_SQUARE --out OUT", "train: error: NOT_SQUARE: the model takes square camera images of one "
     "size, the sensor description's cameras.output is 128 x 64 px"),
    ("recalibrate --sensor NOT_SQUARE --out OUT", "recalibrate: error: NOT_SQUARE: the model takes square camera"),
    # "ModelConfig: image_size 100 must be divisible by 2^4", naming neither the file nor the option (walkthrough)
    ("train --sensor ODD_SIZE --out OUT", "train: error: ODD_SIZE: the cameras' output images, 100 x 100 px, must be a "
     "multiple of 16 px: each of the model's 4 conv blocks (--conv-channels) halves them; make cameras.output a "
     "multiple of 16"),
])
def test_bad_arguments_are_refused_with_an_error_line_before_anything_runs(capsys, tmp_path, one_camera_sensor, args,
                                                                            message):
    not_square = tmp_path / "not_square.yaml"
    not_square.write_text((CONFIG / "sensor.yaml").read_text().replace("output: {width: 128, height: 128}",
                                                                        "output: {width: 128, height: 64}"))
    odd_size = tmp_path / "odd_size.yaml"
    odd_size.write_text((CONFIG / "sensor.yaml").read_text().replace("output: {width: 128, height: 128}",
                                                                      "output: {width: 100, height: 100}"))
    names = {"OUT": tmp_path / "out", "ONE_CAMERA": one_camera_sensor, "NOT_SQUARE": not_square, "ODD_SIZE": odd_size}
    message = message.replace("NOT_SQUARE", str(not_square)).replace("ODD_SIZE", str(odd_size))
    message = message.replace("ONE_CAMERA", str(one_camera_sensor)).replace("OUT", str(tmp_path / "out"))
    command, *words = [names.get(w, w) for w in args.split()]
    # Should a setting pass unchecked, train and recalibrate would only train briefly on a few frames.
    brief = ["--frames", "30", "--epochs", "1", "--head-epochs", "1", "--head-cycles", "1", *TINY]
    assert refusal(capsys, command, *(brief if command in ("train", "recalibrate") else []), *words).startswith(
        f"tactile-fusion {message}")
    assert not (tmp_path / "out").exists()


@pytest.mark.parametrize(("command", "option", "what"), [
    ("eval", "--dataset", "a data set directory"), ("eval", "--scene", "a scene or a YAML file"),
    ("eval", "--model", "a model directory"), ("bench", "--model", "a model directory"),
    ("train", "--sensor", "a sensor description YAML"), ("recalibrate", "--out", "a directory"),
])
def test_an_empty_file_or_directory_name_is_refused(capsys, tmp_path, command, option, what):
    """It was taken as no option: `eval --dataset ""` evaluated the default test set without a word (found in
    review)."""
    needs_out = command in ("train", "recalibrate") and option != "--out"
    line = refusal(capsys, command, *(["--out", tmp_path / "out"] if needs_out else []), option, "")
    assert line == f"tactile-fusion {command}: error: argument {option}: must name {what}, got ''"
    assert not (tmp_path / "out").exists()


def test_too_few_training_frames_for_batch_normalisation_is_an_error_line(capsys, tmp_path, one_camera_sensor):
    """3 frames (the fewest a split takes) leave one training frame: a one-camera model needs two. It was a plain
    ValueError, a traceback."""
    line = refusal(capsys, "train", "--sensor", one_camera_sensor, "--frames", "3", "--epochs", "1", "--head-epochs",
                   "1", "--batch-size", "2", "--head-batch-size", "2", "--head-extra-draws", "0", "--out",
                   tmp_path / "out", *TINY)
    assert line == ("tactile-fusion train: error: fit: a 1-camera model needs at least 2 training frames (batch "
                    "normalisation needs two images per batch), got 1; give more frames"), line


def test_the_most_threads_are_taken():
    from tactile_fusion.cli import MAX_THREADS, build_parser

    assert MAX_THREADS == 1024 and build_parser().parse_args(["bench", "--threads", "1024"]).threads == MAX_THREADS


def test_eval_of_a_dataset_takes_its_first_frames_shows_progress_and_plots_the_sensors_bins(tiny_model, tmp_path,
                                                                                            capsys, monkeypatch):
    from tactile_description import load_sensor
    from tactile_fusion import plots
    from tactile_fusion.cli import main
    from tactile_sim import Simulator, load_scene, write_dataset

    out, _ = tiny_model
    sensor = load_sensor(CONFIG / "sensor.yaml")
    data = write_dataset(Simulator(sensor), load_scene("shear", sensor), tmp_path / "data", progress=False, frames=6)
    plotted, plot = [], plots.plot_fz_maps

    def plotted_too(*args, **kwargs):  # the figure drawn for real (it was replaced; found in an audit of the tests)
        plotted.append(kwargs["bin_size_mm"])
        return plot(*args, **kwargs)

    monkeypatch.setattr(plots, "plot_fz_maps", plotted_too)
    assert main(["eval", "--model", str(out), "--dataset", str(data), "--frames", "4", "--out", str(tmp_path / "eval"),
                 "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["data_sets"]["dataset data"]["frames"] == 4
    assert plotted == [pytest.approx((49.0 / 25, 51.0 / 26))]  # a bin of the sensor's grid, in millimetres
    assert (tmp_path / "eval" / "fz_map_dataset_data.png").stat().st_size > 0
    assert main(["eval", "--model", str(out), "--dataset", str(data), "--frames", "2"]) == 0
    assert "evaluate shear" in capsys.readouterr().err  # the progress bar, unless --quiet or --json
    assert "--split applies to --scene only" in refusal(capsys, "eval", "--model", out, "--dataset", data, "--split",
                                                        "test")


def test_eval_refuses_to_write_into_a_model_directory(tiny_model, capsys):
    """It replaced the model's metrics.json, the per-backend figures bench reports, with its own report."""
    out, _ = tiny_model
    recorded = (out / "metrics.json").read_bytes()
    assert f"--out {out} holds a model (model.json): eval would replace the model's metrics.json" in refusal(
        capsys, "eval", "--model", out, "--frames", "2", "--out", out)
    assert (out / "metrics.json").read_bytes() == recorded


def test_export_refuses_a_model_of_another_sensor_before_it_simulates_frames(tiny_model, capsys, monkeypatch):
    from tactile_fusion import pipeline

    def simulated(*args, **kwargs):
        raise AssertionError("frames were simulated for a model that does not fit the sensor")

    monkeypatch.setattr(pipeline, "simulate_frames", simulated)
    out, _ = tiny_model
    for option in ("--measure", "--fit-threshold"):
        assert "the model is for cameras" in refusal(capsys, "export", "--model", out, option, "--sensor",
                                                     CONFIG / "skin_3x3.yaml")


def test_export_measure_refuses_a_description_other_than_the_one_the_model_was_trained_for(tiny_model, tmp_path,
                                                                                           capsys, monkeypatch):
    """--measure and --fit-threshold simulate the training scene again: with a moved camera, its frames would not be
    those the model was trained on, and the model's own records would be rewritten with them."""
    from tactile_fusion import pipeline

    def simulated(*args, **kwargs):
        raise AssertionError("frames were simulated with a description the model was not trained for")

    monkeypatch.setattr(pipeline, "simulate_frames", simulated)
    out, _ = tiny_model
    moved = tmp_path / "moved.yaml"
    moved.write_text((CONFIG / "sensor.yaml").read_text().replace("cam3, position_mm: [36.75,",
                                                                  "cam3, position_mm: [36.0,"))
    before = {f.name: file_sha256(f) for f in out.iterdir()}
    for option in ("--measure", "--fit-threshold"):
        assert refusal(capsys, "export", "--model", out, option, "--sensor", moved).endswith(
            f"the sensor description {moved} is not the one the model was trained for: cameras[cam3].position_m "
            "changed since: --measure and --fit-threshold simulate its training scene again, which with this "
            "description is not the data it was trained on; give the description it was trained with (--sensor FILE)")
    assert {f.name: file_sha256(f) for f in out.iterdir()} == before


def test_resuming_a_finished_model_is_refused_and_leaves_it_as_it_is(tiny_model, tmp_path, capsys):
    out, _ = tiny_model
    finished = tmp_path / "model"
    shutil.copytree(out, finished)
    before = {f.name: file_sha256(f) for f in finished.iterdir()}
    message = refusal(capsys, "train", "--out", finished, "--resume", "--frames", "30", "--epochs", "1",
                      "--head-epochs", "1", *TINY)
    assert message.startswith(f"tactile-fusion train: error: --resume: {finished} holds a finished model (model.json) "
                              "and no checkpoint to resume from")
    assert {f.name: file_sha256(f) for f in finished.iterdir()} == before


def test_a_model_trained_again_drops_the_old_records_before_it_writes_its_files(tiny_model, tmp_path, monkeypatch):
    """A stop while the new model's files were written left the old training.json and metrics.json beside them, and
    eval measured the new model on the old test split (found by a walkthrough)."""
    from tactile_fusion import pipeline
    from tactile_fusion.cli import main

    out, _ = tiny_model
    again = tmp_path / "model"
    shutil.copytree(out, again)

    def failing_export(model, out_dir):
        raise OSError("the disk filled up while the graphs were written")

    monkeypatch.setattr(pipeline, "export_all", failing_export)
    with pytest.raises(OSError, match="the disk filled up"):
        main(["train", "--out", str(again), "--frames", "30", "--epochs", "1", "--head-epochs", "1", *TINY])
    assert (again / MODEL_JSON).is_file() and not (again / TRAINING_JSON).exists()
    assert not (again / METRICS_JSON).exists() and not (again / "fz_map.png").exists()


def test_training_from_scratch_over_the_checkpoints_of_an_interrupted_one_is_refused(tmp_path, capsys):
    """Without --resume the new training overwrote the end-to-end checkpoint and left the head phases' of the other
    training beside it, which a later --resume refused (found by a walkthrough)."""
    out = tmp_path / "model"
    out.mkdir()
    (out / "checkpoint_head.pt").write_bytes(b"the head phase of an interrupted training")
    message = refusal(capsys, "train", "--out", out, "--frames", "30", "--epochs", "1", "--head-epochs", "1", *TINY)
    assert message == (f"tactile-fusion train: error: {out} holds the checkpoints of an interrupted training "
                       "(checkpoint_head.pt): continue it with --resume, delete them to train from scratch, or "
                       "choose another --out")
    assert [p.name for p in out.iterdir()] == ["checkpoint_head.pt"]


def test_a_model_that_outputs_inf_is_an_error_line_not_a_traceback(tiny_model, tmp_path, capsys):
    import torch

    out, _ = tiny_model
    broken = tmp_path / "model"
    shutil.copytree(out, broken)
    weights = torch.load(broken / STATE_DICT)
    weights["fusion.expand.bias"][0] = float("inf")
    torch.save(weights, broken / STATE_DICT)
    assert "torch fp32: the model produced NaN or Inf from finite inputs" in refusal(
        capsys, "eval", "--model", broken, "--backend", "torch", "--frames", "2", "--quiet")
    # A weight beyond float16's range: fp32 runs, fp16 overflows, and re-exporting (the advice given) cannot help
    weights["fusion.expand.bias"][0] = 1e6
    torch.save(weights, broken / STATE_DICT)
    assert refusal(capsys, "eval", "--model", broken, "--backend", "torch", "--precision", "fp16", "--frames", "2",
                   "--quiet").endswith("torch fp16: the model produced NaN or Inf from finite inputs: its weights or "
                                       "activations exceed float16's range (65504), as those of a training that "
                                       "diverged do; use fp32, or retrain the model (if fp32 fails too, the model "
                                       "file is corrupt)")


@pytest.fixture
def shipped_copy(tmp_path) -> Path:
    """A copy of the shipped model directory, to damage."""
    return Path(shutil.copytree(default_model_dir(), tmp_path / "model"))


def _edited_json(path: Path, change) -> None:
    data = json.loads(path.read_text())
    change(data)
    path.write_text(json.dumps(data))


@pytest.mark.parametrize("name, damage, command, message", [
    (ONNX_FILES["fp32"], lambda p: p.write_bytes(b""), "eval", r"model.onnx cannot be loaded by ONNX Runtime "
     r"\(.*INVALID_ARGUMENT.*No graph was found.*\): .*re-export it \(tactile-fusion export --model "),
    (ONNX_FILES["fp32"], lambda p: p.write_bytes(b""), "bench", "model.onnx cannot be loaded by ONNX Runtime"),
    (STATE_DICT, lambda p: torch.save([1.0, 2.0], p), "eval --backend torch",
     r"model.pt cannot be read or does not fit model.json \(it holds a list, not a state dict\): .*retrain"),
    (STATE_DICT, lambda p: (p.unlink(), p.mkdir()), "eval --backend torch",
     r"model.pt cannot be read or does not fit model.json \(.*Is a directory"),
    (STATE_DICT, lambda p: torch.save(torch.zeros(3), p), "eval --backend torch",
     r"model.pt cannot be read or does not fit model.json \(it holds a Tensor, not a state dict\)"),
    (MODEL_JSON, lambda p: _edited_json(p, lambda d: d.update(format_version="1")), "eval",
     "model.json: format_version '1' is not 1; retrain the model"),
    (TRAINING_JSON, lambda p: _edited_json(p, lambda d: d["data"].update(split_targets_sha256=["0" * 64])), "eval",
     r"training.json: data.split_targets_sha256 must be an object \(the SHA-256 of each split's forces\), "
     r"got \['0+'\]; restore it from a copy"),
    (METRICS_JSON, lambda p: _edited_json(p, lambda d: d["backends"]["onnxruntime_fp32"].update(
        rmse_bin_n=[0, 0, None])),
     "bench --runs 1", r"metrics.json: the figures of onnxruntime_fp32 must be numbers \(frames a whole number >= 1\), "
     r"got \{'rmse_bin_fz_n': None\}; "
     r"measure the model again \(tactile-fusion export --model"),
    (METRICS_JSON, lambda p: _edited_json(p, lambda d: d["backends"]["torch_fp16"].update(frames=-3)),
     "bench --runs 1", r"metrics.json: the figures of torch_fp16 must be numbers \(frames a whole number >= 1\), "
     r"got \{'frames': -3\}"),
])
def test_a_damaged_file_of_a_model_directory_is_one_error_line_naming_it(shipped_copy, capsys, name, damage, command,
                                                                         message):
    """Refused before anything is evaluated or benchmarked (bench --runs 1 would otherwise run to its end)."""
    damage(shipped_copy / name)
    line = refusal(capsys, *command.split(), "--model", shipped_copy, "--quiet")
    assert re.match(f"tactile-fusion {command.split()[0]}: error: {re.escape(str(shipped_copy))}/{message}", line), line


def test_bench_names_no_frame_count_for_figures_that_record_none(shipped_copy, capsys):
    """"frames" may be null (figures recorded before it was): bench printed "(None of its frames)"."""
    from tactile_fusion.cli import main

    _edited_json(shipped_copy / METRICS_JSON, lambda d: d["backends"]["torch_fp16"].update(frames=None))
    assert main(["bench", "--model", str(shipped_copy), "--runs", "1"]) == 0
    line = [line for line in capsys.readouterr().out.splitlines() if line.startswith("torch_fp16")][0]
    assert "test split Fz RMSE" in line and "of its frames" not in line, line


@pytest.mark.parametrize("command", ["eval", "train", "recalibrate"])
@pytest.mark.parametrize("out", ["file", "file/plots"])
def test_an_out_that_cannot_be_written_is_refused_before_any_data_is_read(tmp_path, capsys, out, command):
    """eval's plots, train's model and the recalibration study's report (written after half an hour): before,
    eval and train failed with a traceback after reading or simulating the data, the study at its very end."""
    (tmp_path / "file").write_text("")
    # Checked before the data set is read: the dataset that is not there is not what it reports.
    line = refusal(capsys, command, "--out", tmp_path / out, "--dataset", tmp_path / "no_data", "--quiet")
    assert line.startswith(f"tactile-fusion {command}: error: --out {tmp_path / out} cannot be written to as a "
                           f"directory ({'File exists' if out == 'file' else 'Not a directory'}"), line
    assert line.endswith("give a directory that can be created and written to")


@pytest.fixture(scope="module")
def refused_datasets(tmp_path_factory) -> dict[str, Path]:
    """Datasets that eval, train and recalibrate refuse: one that is not there, one whose meta.json is cut short, and
    one of the nine-camera skin (3 frames)."""
    from tactile_description import load_sensor
    from tactile_sim import Simulator, load_scene, write_dataset

    root = tmp_path_factory.mktemp("refused")
    skin = load_sensor(CONFIG / "skin_3x3.yaml")
    other_sensor = write_dataset(Simulator(skin), load_scene("paper_grid", skin), root / "skin", progress=False,
                                 frames=3)
    damaged = Path(shutil.copytree(other_sensor, root / "damaged"))
    (damaged / "meta.json").write_text("{")
    return {"missing": root / "missing", "damaged": damaged, "other_sensor": other_sensor}


@pytest.mark.parametrize("command", ["eval", "train", "recalibrate"])
@pytest.mark.parametrize("dataset, message", [
    ("missing", "is not a data set: no meta.json"),
    ("damaged", "meta.json is not readable UTF-8 JSON"),
    ("other_sensor", "skin has cameras ['cam0'"),
])
def test_a_refused_dataset_leaves_no_out_directory_that_the_command_created(refused_datasets, tmp_path, capsys,
                                                                              command, dataset, message):
    """--out is created and tried before the dataset is read (the test above); once the dataset is refused, the
    directories made for --out are gone again (before: an empty --out, here with its parent, stayed). One that existed
    stays."""
    new, existing = tmp_path / "results" / "out", tmp_path / "existing"
    existing.mkdir()
    for out in (new, existing):
        assert message in refusal(capsys, command, "--out", out, "--dataset", refused_datasets[dataset], "--quiet")
    assert list(tmp_path.iterdir()) == [existing] and not any(existing.iterdir())


def test_an_export_that_cannot_write_a_graph_leaves_the_previous_one_whole(shipped_copy, capsys):
    graph = shipped_copy / ONNX_FILES["fp32"]
    before = {f.name: file_sha256(f) for f in shipped_copy.iterdir()}
    partial = graph.with_name(graph.name + PARTIAL_SUFFIX)
    partial.symlink_to("/dev/full")  # where the graph is written first, on a full disk
    assert refusal(capsys, "export", "--model", shipped_copy) == (
        f"tactile-fusion export: error: {graph} cannot be written (No space left on device): make room on the disk or "
        f"make {shipped_copy} writable, then export again (tactile-fusion export --model {shipped_copy})")
    assert not partial.is_symlink()
    assert {f.name: file_sha256(f) for f in shipped_copy.iterdir()} == before


def test_an_export_that_cannot_write_the_int8_graphs_intermediate_file_is_one_error_line(shipped_copy, capsys):
    int8 = shipped_copy / ONNX_FILES["int8"]
    prepared = int8.with_name(int8.stem + ".prep.onnx")
    prepared.symlink_to("/dev/full")
    assert refusal(capsys, "export", "--model", shipped_copy).startswith(
        f"tactile-fusion export: error: {int8} cannot be written (No space left on device)")
    # The int8 graph of the model before is gone (it must not stay beside a new float graph), and no file is half there.
    assert not prepared.is_symlink() and not int8.exists()
    assert not list(shipped_copy.glob(f"*{PARTIAL_SUFFIX}"))
