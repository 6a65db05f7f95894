"""ONNX export and the inference backends behind one interface: agreement, input checks, precisions."""

import dataclasses
import json
import math
import re
import shutil

import numpy as np
import onnx
import pytest
import torch

from tactile_description import load_sensor
from tactile_fusion.artifacts import (
    MODEL_JSON,
    ONNX_FILES,
    PARTIAL_SUFFIX,
    STATE_DICT,
    WEIGHTS_FIELDS_KEY,
    ModelFileError,
    check_model_fits,
    load_model,
    model_fields,
    replace_written,
    save_model,
    sensor_changes,
    sensor_changes_warning,
    write_json,
    write_torch_file,
)
from tactile_fusion.camera_out import rest_view, with_cameras_at_rest
from tactile_fusion.export import export_onnx, fusion_node_names, quantize_int8
from tactile_fusion.inference import BACKENDS, InputError, OnnxRuntimePredictor, TorchPredictor, load_predictor
from tactile_fusion.model import ForceFusionNet, ModelConfig
from tactile_fusion.pipeline import export_all
from tactile_fusion.sources import ImageSource
from tactile_fusion.training import TrainConfig, build_model, fit

CAMERAS = ("left", "right")


@pytest.fixture(scope="module", params=["sigmoid", "relu"])
def model_dir(tmp_path_factory, make_frames, request):
    """A tiny model trained for a few epochs on synthetic frames, saved and exported in every precision; one with
    each feature activation."""
    frames = make_frames(40, seed=4)
    config = ModelConfig(image_size=16, conv_channels=(4, 4), hidden_features=16, camera_features=12,
                         fusion_rank=None, feature_activation=request.param)
    scale = torch.tensor([0.01, 0.005, 0.1])
    model = build_model(config, frames.camera_ids, 3, 4, scale, seed=0)
    fit(model, ImageSource(frames.subset(np.arange(32)), scale), ImageSource(frames.subset(np.arange(32, 40)), scale),
        TrainConfig(max_epochs=3, batch_size=4, learning_rate=1e-2))
    out = tmp_path_factory.mktemp("model")
    save_model(model, out)
    export_all(model, out)
    return out, frames


def test_exported_graphs_pass_the_onnx_checker_and_keep_the_interface(model_dir):
    out, _ = model_dir
    for name in ONNX_FILES.values():
        proto = onnx.load(str(out / name))
        onnx.checker.check_model(proto, full_check=True)
        assert [i.name for i in proto.graph.input] == ["images", "reference"]
        assert proto.graph.input[0].type.tensor_type.elem_type == onnx.TensorProto.UINT8
        assert proto.graph.output[0].type.tensor_type.elem_type == onnx.TensorProto.FLOAT


def test_onnxruntime_equals_torch_within_1e_5_newton_per_bin(model_dir):
    out, frames = model_dir
    ort = load_predictor(out, "onnxruntime", "fp32")
    pt = load_predictor(out, "torch", "fp32")
    assert isinstance(ort, OnnxRuntimePredictor) and isinstance(pt, TorchPredictor)
    a = ort.predict_batch(frames.images, frames.reference)
    b = pt.predict_batch(frames.images, frames.reference)
    assert a.shape == b.shape == (len(frames), 3, 4, 3) and a.dtype == np.float32
    assert np.abs(a).max() > 1e-3  # the comparison is not between two zero maps
    np.testing.assert_allclose(a, b, rtol=0, atol=1e-5)
    single = ort.predict(frames.images[0], frames.reference)
    np.testing.assert_allclose(single, a[0], rtol=0, atol=1e-6)


def test_int8_keeps_the_fusion_layer_in_float_and_stays_close(model_dir):
    out, frames = model_dir
    proto = onnx.load(str(out / ONNX_FILES["int8"]))
    # By the exported names, independently of fusion_node_names: the fusion layer's matrix product stays float, the
    # two fully connected layers' (renamed by ONNX Runtime when it folds their batch norm and splits Gemm into
    # MatMul + Add) are int8.
    products = {n.name: n.op_type for n in proto.graph.node if n.op_type in ("Gemm", "MatMul", "MatMulInteger")}
    fusion = {name for name in products if name.startswith("/fusion/")}
    assert len(fusion) == 1 and {products[name] for name in fusion} <= {"Gemm", "MatMul"}
    assert sorted(products[name] for name in products if name not in fusion) == ["MatMulInteger", "MatMulInteger"]
    assert set(fusion_node_names(out / ONNX_FILES["fp32"])) & {name.removesuffix("_MatMul") for name in fusion}
    fp32 = load_predictor(out, "onnxruntime", "fp32").predict_batch(frames.images, frames.reference)
    for precision, bound in (("int8", 0.05), ("fp16", 0.005)):
        low = load_predictor(out, "onnxruntime", precision).predict_batch(frames.images, frames.reference)
        assert np.isfinite(low).all()
        # Relative to the largest predicted force: the shipped model's measured errors are in metrics.json.
        assert np.abs(low - fp32).max() <= bound * np.abs(fp32).max(), precision
    half = load_predictor(out, "torch", "fp16").predict_batch(frames.images, frames.reference)
    assert np.abs(half - fp32).max() <= 0.005 * np.abs(fp32).max()


def test_int8_export_refuses_a_graph_whose_fusion_layer_got_quantized(model_dir, tmp_path, monkeypatch):
    """If the exclusion missed the fusion layer (ONNX Runtime renamed its nodes), no int8 graph is written, and the
    one of an earlier export does not stay behind as if it were this model's."""
    import tactile_fusion.export as export

    out, _ = model_dir
    shutil.copy(out / ONNX_FILES["int8"], tmp_path / "int8.onnx")
    monkeypatch.setattr(export, "fusion_node_names", lambda path: [])  # excludes nothing
    with pytest.raises(RuntimeError, match="quantized the fusion layer"):
        quantize_int8(out / ONNX_FILES["fp32"], tmp_path / "int8.onnx")
    assert list(tmp_path.iterdir()) == []  # no graph, no intermediate file


def test_float_grey_levels_give_the_uint8_result_and_camera_order_can_be_named(model_dir):
    out, frames = model_dir
    predictor = load_predictor(out)
    images, reference = frames.images[3], frames.reference
    expected = predictor.predict(images, reference)
    np.testing.assert_array_equal(predictor.predict(images.astype(np.float32), reference.astype(np.float64)),
                                  expected)
    swapped = predictor.predict(images[::-1], reference[::-1], camera_ids=CAMERAS[::-1])
    np.testing.assert_array_equal(swapped, expected)


def test_a_camera_marked_broken_is_shown_at_rest(model_dir):
    out, frames = model_dir
    predictor = load_predictor(out)
    images, reference = frames.images[5].copy(), frames.reference
    images[1] = 0  # a black frame from a dropped camera
    masked = predictor.predict(images, reference, camera_ok=np.array([True, False]))
    substituted = images.copy()
    substituted[1] = rest_view(reference)[1]
    np.testing.assert_array_equal(masked, predictor.predict(substituted, reference))
    # The view at rest: the reference with one grey level of noise, the same pattern every time.
    noise = rest_view(reference).astype(np.int16) - reference
    assert 0.8 < noise.std() < 1.2 and np.abs(noise).max() <= 6
    np.testing.assert_array_equal(rest_view(reference), rest_view(reference.copy()))
    with pytest.raises(InputError, match="camera_ok"):
        predictor.predict_batch(frames.images[:2], reference, camera_ok=np.ones(2, dtype=bool))
    # 1 and 0 mean what True and False do; strings, NaN or 2 were read as True, the broken camera as it was (review)
    for same in (np.array([1, 0]), np.array([1.0, 0.0]), [np.bool_(True), False]):
        np.testing.assert_array_equal(predictor.predict(images, reference, camera_ok=same), masked)
    for bad in (["True", "False"], [1, np.nan], [1, 2], [True, None]):
        with pytest.raises(InputError, match=r"camera_ok: expected True or False \(or 1 or 0\) per camera, got"):
            predictor.predict(images, reference, camera_ok=bad)


def test_a_camera_whose_image_is_its_reference_is_shown_at_rest(model_dir):
    """A difference of exactly 0 (a still image as the source, a lens cap from start-up, a scene without noise) is
    shown as the camera at rest, as a camera marked broken is, with or without camera_ok, in every backend path."""
    out, frames = model_dir
    predictor = load_predictor(out)
    images, reference = frames.images[5].copy(), frames.reference
    images[1] = reference[1]
    at_rest = images.copy()
    at_rest[1] = rest_view(reference)[1]
    np.testing.assert_array_equal(with_cameras_at_rest(images[None], reference, None)[0], at_rest)
    expected = predictor.predict(at_rest, reference)
    np.testing.assert_array_equal(predictor.predict(images, reference), expected)
    np.testing.assert_array_equal(predictor.predict(images, reference, camera_ok=np.array([True, True])), expected)
    np.testing.assert_array_equal(predictor.predict_batch(images[None], reference)[0], expected)
    swapped = predictor.predict(images[::-1], reference[::-1], camera_ids=CAMERAS[::-1])
    np.testing.assert_array_equal(swapped, expected)
    # One pixel off the reference is a frame of its own.
    images[1, 0, 0] ^= 1
    np.testing.assert_array_equal(with_cameras_at_rest(images[None], reference, None)[0], images)


@pytest.mark.parametrize("backend", ["onnxruntime", "torch"])
def test_bad_inputs_raise_clear_errors_and_never_return_nan(model_dir, backend):
    out, frames = model_dir
    predictor = load_predictor(out, backend)
    images, reference = frames.images[0], frames.reference
    broken = images.astype(np.float32)
    broken[1, 4, 7] = np.nan
    with pytest.raises(InputError, match=r"images: contains NaN.*index \(1, 4, 7\)"):
        predictor.predict(broken, reference)
    with pytest.raises(InputError, match=r"reference: float grey levels must lie in \[0, 255\]"):
        predictor.predict(images, reference.astype(np.float32) * 2.0)
    with pytest.raises(InputError, match=r"images: expected shape \(2, 16, 16\)"):
        predictor.predict(images[:1], reference)
    with pytest.raises(InputError, match=r"expected shape \('B', 2, 16, 16\)"):
        predictor.predict_batch(images, reference)
    with pytest.raises(InputError, match="expected uint8"):
        predictor.predict(images.astype(np.int32), reference)
    with pytest.raises(InputError, match="numpy array"):
        predictor.predict(images.tolist(), reference)
    with pytest.raises(InputError, match=r"unknown cameras \['cam9'\]"):
        predictor.predict(images, reference, camera_ids=("left", "cam9"))
    with pytest.raises(InputError, match="once"):
        predictor.predict(images, reference, camera_ids=("left", "left"))


@pytest.mark.parametrize("level", [0, 255])
def test_black_and_saturated_frames_give_finite_forces_in_every_precision(model_dir, level):
    out, frames = model_dir
    frame = np.full_like(frames.images[0], level)
    for backend, precision in (("onnxruntime", "fp32"), ("onnxruntime", "int8"), ("onnxruntime", "fp16"),
                               ("torch", "fp16")):
        assert np.isfinite(load_predictor(out, backend, precision).predict(frame, frames.reference)).all()


@pytest.mark.parametrize("backend", ["onnxruntime", "torch"])
def test_a_batch_of_no_frames_gives_no_forces_for_uint8_and_float_images(model_dir, backend):
    out, frames = model_dir
    predictor = load_predictor(out, backend)
    for dtype in (np.uint8, np.float32):
        empty = np.empty((0, 2, 16, 16), dtype=dtype)
        forces = predictor.predict_batch(empty, frames.reference.astype(dtype))
        assert forces.shape == (0, 3, 4, 3) and forces.dtype == np.float32


def _edited_json(path, change):
    description = json.loads(path.read_text())
    change(description)
    path.write_text(json.dumps(description))


#: (file, backend, how it is damaged, what the error says): each a damaged copy of a model directory.
DAMAGED = [
    (MODEL_JSON, "onnxruntime", lambda p: p.write_text(p.read_text()[:40]), "model.json is not readable UTF-8 JSON"),
    (MODEL_JSON, "torch", lambda p: p.write_text("[1, 2]"), "model.json holds a JSON list, not an object"),
    (MODEL_JSON, "onnxruntime", lambda p: (p.unlink(), p.mkdir()), "model.json is not readable UTF-8 JSON"),
    (MODEL_JSON, "onnxruntime", lambda p: _edited_json(p, lambda d: d.pop("rows")),
     "model.json: rows must be a whole number >= 1, got None"),
    (MODEL_JSON, "torch", lambda p: _edited_json(p, lambda d: d.pop("camera_ids")),
     "model.json: camera_ids must be a non-empty list"),
    (MODEL_JSON, "onnxruntime", lambda p: _edited_json(p, lambda d: d["model_config"].pop("conv_channels")),
     "model.json: model_config .* is not a model configuration"),
    (MODEL_JSON, "torch", lambda p: _edited_json(p, lambda d: d.update(force_scale_n=[1.0, -1.0, 1.0])),
     "model.json: ForceFusionNet: force_scale_n must be 3 finite positive numbers"),
    # allocated 48 TB for the weights (a traceback) before the sensor check (found in review)
    (MODEL_JSON, "torch", lambda p: _edited_json(p, lambda d: d.update(rows=10**6, cols=10**6)),
     r"model.json: rows x cols is 1000000 x 1000000 bins, more than any sensor description takes \(16384\)"),
    (MODEL_JSON, "torch", lambda p: _edited_json(p, lambda d: d.update(cols=5)),
     r"model.pt holds the weights of another model than its model.json describes \(cols \d+ in the weights, 5 in "),
    (STATE_DICT, "torch", lambda p: p.write_bytes(p.read_bytes()[:300]), "model.pt cannot be read"),
    (STATE_DICT, "torch", lambda p: p.write_bytes(b"not a state dict"), "model.pt cannot be read"),
    # Bytes on which torch's safe unpickler raised KeyError, IndexError, struct.error: tracebacks (found in review)
    (STATE_DICT, "torch", lambda p: p.write_bytes(b"hello world"), r"model.pt cannot be read .*\(KeyError: "),
    (STATE_DICT, "torch", lambda p: p.write_bytes(b"(ello world"), r"model.pt cannot be read .*\(IndexError: "),
    (STATE_DICT, "torch", lambda p: p.write_bytes(b"J\x00"), r"model.pt cannot be read .*\(error: "),
    (ONNX_FILES["fp32"], "onnxruntime", lambda p: p.write_bytes(p.read_bytes()[:300]),
     r"model.onnx cannot be loaded by ONNX Runtime .*INVALID_PROTOBUF.*re-export it \(tactile-fusion export"),
]


@pytest.mark.parametrize("name, backend, damage, message", DAMAGED)
def test_a_damaged_model_file_is_refused_naming_the_file_and_what_to_do(model_dir, tmp_path, name, backend, damage,
                                                                        message):
    out, _ = model_dir
    damaged = tmp_path / "model"
    shutil.copytree(out, damaged)
    damage(damaged / name)
    with pytest.raises(ModelFileError, match=f"{damaged}/{message}") as error:
        load_predictor(damaged, backend)
    assert "retrain" in str(error.value) or "re-export" in str(error.value)


def test_missing_model_and_unknown_backend_are_explained(tmp_path, model_dir):
    with pytest.raises(ModelFileError, match="tactile-fusion train"):
        load_predictor(tmp_path)
    out, _ = model_dir
    with pytest.raises(ValueError, match="the torch backend runs fp32, fp16, not 'int8'"):
        load_predictor(out, "torch", "int8")
    with pytest.raises(ValueError, match="backend must be one of"):
        load_predictor(out, "tensorrt")
    # ONNX Runtime took -1 for all cores; torch refused 0 with its own RuntimeError (found in review)
    for backend, threads in (("onnxruntime", -1), ("torch", 0), ("onnxruntime", 1025), ("torch", 1.5)):
        with pytest.raises(ValueError, match=f"threads must be a whole number from 1 to 1024, or None for the "
                                             f"backend's default, got {threads}"):
            load_predictor(out, backend, "fp32", threads)


def test_a_model_of_fz_alone_exports_and_runs_in_every_backend_and_precision(model_dir, tmp_path, fz_only_copy):
    out, frames = model_dir
    model = load_model(out)
    fz = fz_only_copy(model)
    save_model(fz, tmp_path)
    export_all(fz, tmp_path)
    assert json.loads((tmp_path / MODEL_JSON).read_text())["components"] == ["fz"]
    assert load_model(tmp_path).components == ("fz",)
    full = load_predictor(out, "torch").predict_batch(frames.images, frames.reference)
    for backend, precision in (("torch", "fp32"), ("torch", "fp16"), ("onnxruntime", "fp32"),
                               ("onnxruntime", "fp16"), ("onnxruntime", "int8")):
        predictor = load_predictor(tmp_path, backend, precision)
        assert predictor.components == ("fz",)
        predicted = predictor.predict_batch(frames.images, frames.reference)
        assert np.array_equal(predicted[..., :2], np.zeros_like(predicted[..., :2])), (backend, precision)
        tolerance = 1e-5 if precision == "fp32" else 1e-2
        np.testing.assert_allclose(predicted[..., 2], full[..., 2], rtol=0, atol=tolerance,
                                   err_msg=f"{backend} {precision}")


def test_a_model_with_an_fz_threshold_applies_it_in_every_backend_and_precision(model_dir, tmp_path):
    out, frames = model_dir
    plain = load_predictor(out, "torch").predict_batch(frames.images, frames.reference)
    model = load_model(out)
    model.fz_threshold_n = float(np.median(np.abs(plain[..., 2])))  # acts on about half of the bins
    save_model(model, tmp_path)
    export_all(model, tmp_path)  # refuses a quantized fusion layer
    assert json.loads((tmp_path / MODEL_JSON).read_text())["fz_threshold_n"] == model.fz_threshold_n
    assert load_model(tmp_path).fz_threshold_n == model.fz_threshold_n
    for backend, precision in (("torch", "fp32"), ("torch", "fp16"), ("onnxruntime", "fp32"),
                               ("onnxruntime", "fp16"), ("onnxruntime", "int8")):
        predictor = load_predictor(tmp_path, backend, precision)
        assert predictor.fz_threshold_n == model.fz_threshold_n
        predicted = predictor.predict_batch(frames.images, frames.reference)
        # The same precision without the threshold, thresholded here: equal up to float32 rounding.
        expected = load_predictor(out, backend, precision).predict_batch(frames.images, frames.reference)
        expected[..., 2] = np.maximum(expected[..., 2] - model.fz_threshold_n, 0.0)
        assert 0 < np.count_nonzero(expected[..., 2]) < expected[..., 2].size
        assert predicted[..., 2].min() >= 0.0, (backend, precision)
        np.testing.assert_allclose(predicted, expected, rtol=0, atol=1e-6, err_msg=f"{backend} {precision}")


def test_a_graph_of_another_shape_that_names_nothing_in_its_metadata_is_refused_on_loading(model_dir, tmp_path):
    """Graphs exported before 2026-11-24 name nothing; one of another grid failed at its first frame (reshape)."""
    out, _ = model_dir
    model = load_model(out)
    other = build_model(model.config, model.camera_ids, 4, 3, model.force_scale_n, seed=0)  # 4 x 3 bins, not 3 x 4
    save_model(other, tmp_path)
    export_all(other, tmp_path)
    shutil.copy(out / MODEL_JSON, tmp_path / MODEL_JSON)
    graph = tmp_path / ONNX_FILES["fp32"]
    proto = onnx.load(str(graph))
    del proto.metadata_props[:]
    onnx.save(proto, str(graph))
    with pytest.raises(ModelFileError, match=re.escape("(bin_forces_n ['batch', 4, 3, 3] in the graph, ['batch', 3, 4, "
                                                       "3] in model.json): files of two models are mixed")):
        load_predictor(tmp_path, "onnxruntime")
    shutil.copy(out / ONNX_FILES["fp32"], graph)  # the model's own graph
    assert load_predictor(tmp_path, "onnxruntime").rows == 3


def test_a_graph_and_a_model_json_that_differ_in_what_the_graph_has_built_in_are_refused_on_loading(model_dir,
                                                                                                  tmp_path):
    out, _ = model_dir
    model = load_model(out)
    model.fz_threshold_n = 0.002
    save_model(model, tmp_path)
    export_all(model, tmp_path)
    description = json.loads((tmp_path / MODEL_JSON).read_text())
    for name in ONNX_FILES.values():  # every graph names the model.json fields it has built in
        named = {p.key: json.loads(p.value) for p in onnx.load(str(tmp_path / name)).metadata_props}
        assert named == {key: description[key] for key in model_fields(model)}, name
    cameras = description["camera_ids"]
    edits = {"fz_threshold_n": [0.003, None],  # model.json of another model (or of one without a threshold)
             "camera_ids": [cameras[1:] + cameras[:1]],  # the cameras' order, which no shape shows
             "force_scale_n": [[2 * v for v in description["force_scale_n"]]],
             "model_config": [{**description["model_config"], "dropout": 0.2}]}
    for key, values in edits.items():
        for value in values:
            (tmp_path / MODEL_JSON).write_text(json.dumps({**description, key: value}))
            for precision in ONNX_FILES:
                with pytest.raises(ModelFileError, match=rf"exported from another model than its model.json "
                                                         rf"describes \({key} .* in the graph, "
                                                         rf"{re.escape(json.dumps(value))} in model.json\): files "
                                                         "of two models are mixed"):
                    load_predictor(tmp_path, "onnxruntime", precision)
    # A graph exported when graphs named their threshold only is checked for that alone ...
    (tmp_path / MODEL_JSON).write_text(json.dumps({**description, "camera_ids": cameras[::-1]}))
    proto = onnx.load(str(tmp_path / ONNX_FILES["fp32"]))
    onnx.helper.set_model_props(proto, {"fz_threshold_n": "0.002"})
    onnx.save(proto, str(tmp_path / ONNX_FILES["fp32"]))
    assert load_predictor(tmp_path, "onnxruntime").camera_ids == tuple(cameras[::-1])
    (tmp_path / MODEL_JSON).write_text(json.dumps({**description, "fz_threshold_n": None}))
    with pytest.raises(ModelFileError, match=r"\(fz_threshold_n 0.002 in the graph, null in model.json\)"):
        load_predictor(tmp_path, "onnxruntime")
    # ... and one exported before graphs named anything is taken as model.json says.
    del proto.metadata_props[:]
    onnx.save(proto, str(tmp_path / ONNX_FILES["fp32"]))
    assert load_predictor(tmp_path, "onnxruntime").fz_threshold_n is None


def test_weights_and_a_model_json_that_differ_in_what_the_weights_were_trained_with_are_refused(model_dir, tmp_path):
    out, _ = model_dir
    model = load_model(out)
    save_model(model, tmp_path)
    description = json.loads((tmp_path / MODEL_JSON).read_text())
    named = torch.load(tmp_path / STATE_DICT, weights_only=True)[WEIGHTS_FIELDS_KEY]
    assert named == {key: description[key] for key in model_fields(model) if key != "fz_threshold_n"}
    cameras = description["camera_ids"]
    edits = {"camera_ids": cameras[1:] + cameras[:1],  # before: taken, the estimates silently wrong
             "force_scale_n": [2 * v for v in description["force_scale_n"]],  # before: the weights' scale taken
             "model_config": {**description["model_config"], "dropout": 0.2},
             # edits that change the weights' shapes: reported as such, not as torch's size mismatch
             "components": ["fz"] if description["components"] != ["fz"] else ["fx", "fy", "fz"],
             "rows": description["rows"] + 1}
    for key, value in edits.items():
        (tmp_path / MODEL_JSON).write_text(json.dumps({**description, key: value}))
        for precision in BACKENDS["torch"]:
            with pytest.raises(ModelFileError, match=rf"model.pt holds the weights of another model than its "
                                                     rf"model.json describes \({key} .* in the weights, "
                                                     rf"{re.escape(json.dumps(value))} in model.json\): files of "
                                                     "two models are mixed"):
                load_predictor(tmp_path, "torch", precision)
    # The Fz threshold is not the weights': export --fit-threshold sets it in model.json alone.
    (tmp_path / MODEL_JSON).write_text(json.dumps({**description, "fz_threshold_n": 0.004}))
    assert load_predictor(tmp_path, "torch").fz_threshold_n == 0.004
    # A model.pt saved before it named the fields is taken as model.json says.
    state = torch.load(tmp_path / STATE_DICT, weights_only=True)
    del state[WEIGHTS_FIELDS_KEY]
    torch.save(state, tmp_path / STATE_DICT)
    (tmp_path / MODEL_JSON).write_text(json.dumps({**description, "camera_ids": cameras[::-1]}))
    assert load_predictor(tmp_path, "torch").camera_ids == tuple(cameras[::-1])
    # ... but for its force scale, a buffer of every model.pt (before: the weights' scale silently taken).
    scale = [2 * v for v in description["force_scale_n"]]
    (tmp_path / MODEL_JSON).write_text(json.dumps({**description, "force_scale_n": scale}))
    with pytest.raises(ModelFileError, match=rf"\(force_scale_n .* in the weights, {re.escape(json.dumps(scale))} in "
                                             r"model.json\)"):
        load_model(tmp_path)


def test_a_model_json_without_an_fz_threshold_has_none_and_a_bad_one_is_refused(model_dir, tmp_path):
    out, _ = model_dir
    save_model(load_model(out), tmp_path)
    description = json.loads((tmp_path / MODEL_JSON).read_text())
    assert description["fz_threshold_n"] is None
    del description["fz_threshold_n"]  # a model saved before models had one
    (tmp_path / MODEL_JSON).write_text(json.dumps(description))
    assert load_model(tmp_path).fz_threshold_n is None
    export_onnx(load_model(tmp_path), tmp_path / ONNX_FILES["fp32"])
    assert load_predictor(tmp_path, "onnxruntime").fz_threshold_n is None
    for bad in (-0.001, "NaN", "0.002", True, [0.001]):
        (tmp_path / MODEL_JSON).write_text(json.dumps({**description, "fz_threshold_n": bad}))
        for backend in ("torch", "onnxruntime"):
            # named neither the file nor what to do (walkthrough)
            with pytest.raises(ModelFileError, match=re.escape(f"{tmp_path / MODEL_JSON}: fz_threshold_n must be None "
                                                               "or a finite number")):
                load_predictor(tmp_path, backend)


def test_a_model_json_from_before_components_could_be_left_out_estimates_all_three(model_dir, tmp_path):
    out, frames = model_dir
    save_model(load_model(out), tmp_path)
    description = json.loads((tmp_path / MODEL_JSON).read_text())
    del description["components"]
    (tmp_path / MODEL_JSON).write_text(json.dumps(description))
    assert load_model(tmp_path).components == ("fx", "fy", "fz")
    export_onnx(load_model(tmp_path), tmp_path / ONNX_FILES["fp32"])
    assert load_predictor(tmp_path, "onnxruntime").components == ("fx", "fy", "fz")
    for bad in (None, ["fz", "fz"], ["fz", "tz"], [], [["fz"]], [{"fz": 1}]):  # the last two: TypeError before
        (tmp_path / MODEL_JSON).write_text(json.dumps({**description, "components": bad}))
        with pytest.raises(ModelFileError, match=r"components must be distinct names.*; the file is damaged or was "
                                                 "edited: copy the model directory again or retrain it"):
            load_predictor(tmp_path, "onnxruntime")


def test_saved_model_reloads_identically(model_dir, tmp_path):
    out, frames = model_dir
    model = load_model(out)
    save_model(model, tmp_path)
    again = load_model(tmp_path)
    assert isinstance(again, ForceFusionNet) and again.camera_ids == CAMERAS
    for key, value in model.state_dict().items():
        assert torch.equal(value, again.state_dict()[key])


def test_a_missing_model_directory_and_one_without_model_json_are_told_apart(tmp_path):
    with pytest.raises(ModelFileError, match=f"no model in {tmp_path / 'none'}: no such directory; train one"):
        load_predictor(tmp_path / "none")
    with pytest.raises(ModelFileError, match=f"no model in {tmp_path}: model.json is missing; train one"):
        load_predictor(tmp_path)


def test_a_model_must_fit_the_sensor_in_cameras_bins_and_image_size():
    sensor = load_sensor()

    def net(camera_ids, rows=26, cols=25, size=128):
        return ForceFusionNet(ModelConfig(image_size=size), camera_ids, rows, cols)

    check_model_fits(TorchPredictor(net(sensor.camera_ids[::-1])), sensor)  # inputs are matched by id: any order
    check_model_fits(net(sensor.camera_ids), sensor)                        # a torch model is checked the same way
    for wrong, message in ((net(sensor.camera_ids[:3]), r"the model is for cameras .* and 128 x 128 images; the sensor "
                                                        r"description .* 26 x 25 bins and 128 x 128 images: use"),
                           (net(sensor.camera_ids, rows=25), "26 x 25 bins"),
                           (net(sensor.camera_ids, size=64), "64 x 64 images")):
        with pytest.raises(ModelFileError, match=message):
            check_model_fits(TorchPredictor(wrong), sensor)


def test_a_model_names_the_description_it_was_trained_for_and_what_changed_in_it_since(model_dir, tmp_path):
    """model.json keeps the physical description of the sensor the model was trained for: a gel, camera or lens
    edited since, which check_model_fits cannot see, is named in a warning; the model still runs."""
    out, _ = model_dir
    sensor = load_sensor()
    model = load_model(out)
    save_model(model, tmp_path, sensor)
    export_all(model, tmp_path)
    layers = list(sensor.gel_layers)
    layers[1] = dataclasses.replace(layers[1], youngs_modulus_pa=2 * layers[1].youngs_modulus_pa)
    stiffer = dataclasses.replace(sensor, gel_layers=tuple(layers), source="stiffer.yaml")
    reordered = dataclasses.replace(sensor, cameras=sensor.cameras[::-1])  # the model matches cameras by id
    for backend in BACKENDS:
        made_for = load_predictor(tmp_path, backend).made_for
        for same in (sensor, dataclasses.replace(sensor, name="renamed"), reordered):
            assert sensor_changes(made_for, same) == []
            assert sensor_changes_warning(sensor_changes(made_for, same), same) == ""
        assert sensor_changes(made_for, stiffer) == ["gel_layers[particle_layer].youngs_modulus_pa"]
        assert sensor_changes_warning(sensor_changes(made_for, stiffer), stiffer) == (
            "the sensor description stiffer.yaml is not the one the model was trained for: "
            "gel_layers[particle_layer].youngs_modulus_pa changed since; its estimates may be off: retrain it for "
            "this description (tactile-fusion train --sensor FILE), or use the description it was trained with")
    # A model saved without its sensor (as those trained before 2026-11-27) cannot tell: no warning.
    unknown = load_predictor(out).made_for
    assert unknown is None and sensor_changes(unknown, stiffer) is None
    assert sensor_changes_warning(sensor_changes(unknown, stiffer), stiffer) == ""


@pytest.mark.parametrize("entry, problem", [
    ("trueeb2020_4cam", "must be a mapping of ['grid', 'gel_layers', 'particles', 'cameras'], got 'trueeb2020_4cam'"),
    ({}, "lacks ['grid', 'gel_layers', 'particles', 'cameras']"),
    ({"grid": "26x25", "gel_layers": [], "particles": {}, "cameras": []}, "grid and particles must be mappings"),
    ({"grid": {}, "gel_layers": [], "particles": {}, "cameras": 5}, "cameras must be a list of mappings, got 5"),
    ({"grid": {}, "gel_layers": [], "particles": {}, "cameras": [{"camera_id": 1}]},
     "every camera must have its camera_id"),
])
def test_a_damaged_record_of_the_description_a_model_was_trained_for_is_refused(model_dir, tmp_path, entry, problem):
    """Not read as "nothing changed" (an empty mapping) nor as a change to warn of: the file is damaged."""
    out, _ = model_dir
    shutil.copytree(out, tmp_path, dirs_exist_ok=True)
    write_json(tmp_path / MODEL_JSON, {**json.loads((out / MODEL_JSON).read_text()), "sensor": entry})
    with pytest.raises(ModelFileError, match=re.escape(f"model.json: sensor (the sensor description it was trained "
                                                       f"for): {problem}; the file is damaged")):
        load_predictor(tmp_path)


def test_a_json_file_that_cannot_be_written_is_one_error_and_leaves_the_file_before_whole(tmp_path):
    """model.json, training.json and metrics.json are written beside themselves and renamed into place: a full disk
    (the partial file a link to /dev/full) leaves the file before as it was, and says which file and what to do."""
    path = tmp_path / "metrics.json"
    write_json(path, {"rmse_bin_n": [0.0, 0.0, 0.002]})
    before = path.read_bytes()
    partial = path.with_name(path.name + PARTIAL_SUFFIX)
    partial.symlink_to("/dev/full")
    with pytest.raises(ModelFileError, match=rf"{path}.* cannot be written \(No space left on device\): make room"):
        write_json(path, {"rmse_bin_n": [0.0, 0.0, 0.001]})
    assert path.read_bytes() == before and not partial.is_symlink()
    write_json(path, {"rmse_bin_n": [0.0, 0.0, 0.001]})
    assert json.loads(path.read_text()) == {"rmse_bin_n": [0.0, 0.0, 0.001]} and not partial.exists()


def test_weights_that_cannot_be_written_are_one_error_and_leave_no_model_behind(model_dir, tmp_path):
    """model.pt went straight onto its file: a full disk cut it short, with a traceback from torch's writer, and
    model.json, written first, described weights that were not there (found in review). Now model.pt is written
    beside itself (model.partial, here a link to /dev/full) and renamed into place, then model.json."""
    out, _ = model_dir
    model = load_model(out)
    target = tmp_path / "model"
    target.mkdir()
    partial = (target / STATE_DICT).with_suffix(PARTIAL_SUFFIX)
    partial.symlink_to("/dev/full")
    with pytest.raises(ModelFileError, match=rf"{target / STATE_DICT} cannot be written \(.*\): make room"):
        save_model(model, target)
    assert list(target.iterdir()) == []
    save_model(model, target)
    assert sorted(p.name for p in target.iterdir()) == [MODEL_JSON, STATE_DICT]
    assert torch.equal(load_model(target).fusion.expand.weight, model.fusion.expand.weight)


def test_a_torch_file_is_written_into_a_folder_that_does_not_exist_yet(tmp_path):
    """_save_checkpoint made the checkpoint's folder; once it wrote through write_torch_file, that failed there
    ("Parent directory ... does not exist", found in review of the change)."""
    checkpoint = tmp_path / "not" / "yet" / "checkpoint.pt"
    write_torch_file(checkpoint, {"weights": torch.ones(2)}, "run again")
    assert torch.equal(torch.load(checkpoint)["weights"], torch.ones(2))
    assert [p.name for p in checkpoint.parent.iterdir()] == ["checkpoint.pt"]


def test_non_finite_numbers_are_written_to_json_as_null(tmp_path):
    """A training that diverged wrote "train_rmse": Infinity into training.json: no JSON number (found in review)."""
    path = tmp_path / "training.json"
    write_json(path, {"history": [{"train_rmse": math.inf, "val_rmse": math.nan}, {"train_rmse": 0.5}], "ok": 1.0})
    assert json.loads(path.read_text()) == {"history": [{"train_rmse": None, "val_rmse": None}, {"train_rmse": 0.5}],
                                            "ok": 1.0}
    assert "Infinity" not in path.read_text() and "NaN" not in path.read_text()


def test_a_write_cut_off_by_a_stop_signal_leaves_no_partial_file(tmp_path):
    """Only an Exception removed the partial file: one cut off by a Ctrl-C or SIGTERM (a BaseException) was left, and
    a new --out holding it was not removed, nor found holding a checkpoint to resume (found in review)."""
    path = tmp_path / "checkpoint_end_to_end.pt"
    partial = tmp_path / ("checkpoint_end_to_end.pt" + PARTIAL_SUFFIX)

    def cut_off(target):
        target.write_bytes(b"half")
        raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        replace_written(path, partial, cut_off)
    assert list(tmp_path.iterdir()) == []
