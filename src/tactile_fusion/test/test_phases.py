"""The training phases after end-to-end: head on cached features, least-squares fusion fit, recalibration."""

import copy
import json
import math
from dataclasses import fields, replace
from pathlib import Path

import numpy as np
import pytest
import torch

from tactile_description import load_sensor
from tactile_fusion import least_squares, sources
from tactile_fusion.artifacts import MODEL_JSON, TRAINING_JSON
from tactile_fusion.camera_out import rest_view
from tactile_fusion.data import FrameDataError, FrameSet, split_indices
from tactile_fusion.evaluation import predict_torch
from tactile_fusion.fz_threshold import fit_fz_threshold, fit_threshold_and_fusion
from tactile_fusion.inference import load_predictor
from tactile_fusion.least_squares import fit_fusion, fit_fusion_under_threshold
from tactile_fusion.model import ForceFusionNet, ModelConfig, force_scale_from_targets
from tactile_fusion.pipeline import train_and_export, train_model
from tactile_fusion.recalibration import add_camera, checked_fractions, fraction_subset, recalibrate
from tactile_fusion.sources import Augmentation, CachedSource, ImageSource, normalised_rmse
from tactile_fusion.training import (
    END_TO_END_SETTINGS,
    HEAD_SETTINGS,
    NOT_PHASE_SETTINGS,
    SHARED_SETTINGS,
    TrainConfig,
    build_model,
    fit,
    train_phases,
)


def splits(frames):
    split = split_indices(len(frames), seed=3)
    return frames.subset(split["train"]), frames.subset(split["val"])


def model_for(frames, config, seed=0, components=("fx", "fy", "fz")):
    train, _ = splits(frames)
    scale = force_scale_from_targets(torch.from_numpy(train.bin_forces_n))
    return build_model(config, frames.camera_ids, 3, 4, scale, seed, components)


class Interrupt(Exception):
    """Raised by `interrupt_after`: training stops there as after Ctrl-C, its checkpoints written."""


def interrupt_after(n: int):
    """(on_epoch_end callback that raises Interrupt after the n-th epoch of all phases together, the epochs seen)."""
    seen = []

    def callback(epoch, record):
        seen.append(epoch)
        if len(seen) == n:
            raise Interrupt

    return callback, seen


def test_cached_source_predicts_what_the_whole_network_predicts(frames, tiny_config):
    model = model_for(frames, tiny_config).eval()
    train, _ = splits(frames)
    idx = np.array([0, 3, 5])
    with torch.no_grad():
        whole = ImageSource(train, model.force_scale_n).predict(model, idx)
        for cut in ("trunk", "hidden"):
            torch.testing.assert_close(CachedSource(model, train, cut).predict(model, idx), whole)
    with pytest.raises(ValueError, match="cut must be one of"):
        CachedSource(model, train, "fusion")


def test_training_shows_a_camera_that_is_out_at_rest_as_inference_does(frames, tiny_config):
    """A frame with a camera flagged not ok (a dropped or frozen camera in a scene with effects) trains the model on
    what the predictor shows it for that camera (camera_out.rest_view), not on the black or frozen image."""
    model = model_for(frames, tiny_config).eval()
    train, _ = splits(frames)
    broken = train.subset(np.arange(len(train)))
    broken.images[2, 1] = 0  # camera "right" went black in frame 2 and is flagged
    broken.camera_ok[2, 1] = False
    shown = train.subset(np.arange(len(train)))
    shown.images[2, 1] = rest_view(train.reference)[1]
    idx = np.array([1, 2, 4])
    with torch.no_grad():
        expected = ImageSource(shown, model.force_scale_n).predict(model, idx)
        torch.testing.assert_close(ImageSource(broken, model.force_scale_n).predict(model, idx), expected)
        for cut in ("trunk", "hidden"):
            torch.testing.assert_close(CachedSource(model, broken, cut).predict(model, idx), expected)
    np.testing.assert_array_equal(predict_torch(model, broken), predict_torch(model, shown))


@pytest.mark.parametrize("rank", [None, 2])
def test_least_squares_fusion_fit_is_exact_for_a_linear_target(frames, tiny_config, rank):
    """Targets that are an exact linear map (of rank 2, plus a bias) of the model's own features are fitted
    exactly."""
    model = model_for(frames, replace(tiny_config, fusion_rank=rank)).eval()
    train, val = splits(frames)
    teacher = model_for(frames, replace(tiny_config, fusion_rank=2), seed=1).eval()
    teacher.cnn.load_state_dict(model.cnn.state_dict())
    with torch.no_grad():  # a bias far from zero: it lies outside a rank-limited layer's rank and must be fitted
        teacher.fusion.expand.bias.uniform_(-2.0, 2.0)
    for part in (train, val):
        part.bin_forces_n[...] = predict_torch(teacher, part)
    sources = [CachedSource(model, part, "trunk") for part in (train, val)]
    before = normalised_rmse(model, sources[1])
    report = fit_fusion(model, *sources, ridges=(1e-9,))
    assert report["ridge"] == 1e-9 and report["val_rmse_before"] == pytest.approx(before)
    assert normalised_rmse(model, sources[1]) < 1e-5 * before  # float32 weights: about 3e-6 of it


def test_rank_limited_fit_with_fewer_frames_than_the_rank_stays_finite(frames, tiny_config):
    model = model_for(frames, replace(tiny_config, fusion_rank=20)).eval()
    train, val = splits(frames)
    few = [CachedSource(model, train.subset(np.arange(8)), "trunk"), CachedSource(model, val, "trunk")]
    report = fit_fusion(model, *few, ridges=(1e-3,))
    assert np.isfinite(report["val_rmse"]["0.001"])
    assert all(torch.isfinite(p).all() for p in model.fusion.parameters())


@pytest.mark.parametrize("rank", [None, 2])
def test_a_fit_to_the_features_of_a_head_that_diverged_leaves_the_layer_as_it_was(frames, tiny_config, rank):
    """A head learning rate of 1e6 made the features NaN: the solve raised "singular", and with a rank-limited layer
    the SVD raised next (found in review). No ridge gives a fit then; the cycle that diverged is thrown away after."""
    model = model_for(frames, replace(tiny_config, fusion_rank=rank)).eval()
    train, val = splits(frames)
    with torch.no_grad():
        model.cnn.last_layer.linear.weight.fill_(math.nan)
    sources = [CachedSource(model, part, "trunk") for part in (train, val)]
    fusion_before = [p.clone() for p in model.fusion.parameters()]
    report = fit_fusion(model, *sources, ridges=(1e-3, 1e-1))
    assert report["ridge"] is None and report["val_rmse"] == {"0.001": math.inf, "0.1": math.inf}
    assert all(torch.equal(p, q) for p, q in zip(model.fusion.parameters(), fusion_before, strict=True))


@pytest.mark.parametrize("components", [("fx", "fy", "fz"), ("fz",)])
@pytest.mark.parametrize("rank", [None, 2])
def test_least_squares_scores_are_the_validation_rmse_of_the_fitted_model(frames, tiny_config, components, rank):
    """Also for a model that leaves components out: the synthetic frames have Fx and Fy, which it predicts as 0, and
    its score must count them as the model's own validation RMSE does."""
    model = model_for(frames, replace(tiny_config, fusion_rank=rank), components=components).eval()
    train, val = splits(frames)
    sources = [CachedSource(model, part, "trunk") for part in (train, val)]
    report = fit_fusion(model, *sources)
    assert report["ridge"] is not None
    assert report["val_rmse"][str(report["ridge"])] == pytest.approx(normalised_rmse(model, sources[1]), rel=1e-5)
    assert model.fusion.expand.out_features == 3 * 4 * len(components)
    assert np.all(predict_torch(model, val)[..., :3 - len(components)] == 0.0)


def test_the_fits_features_are_the_models_own_batch_by_batch_with_a_column_of_ones_for_the_bias(frames, tiny_config):
    """camera_features writes every batch into one tensor (for the memory of the fit); its rows must be the model's
    features of each frame, whichever batch the frame fell in, and its targets the estimated components."""
    model = model_for(frames, tiny_config, components=("fz",)).eval()
    train, _ = splits(frames)
    source = CachedSource(model, train, "trunk")
    design, targets, unestimated = least_squares.camera_features(model, source, batch_size=4, ones_column=True)
    assert len(train) % 4 and design.dtype == targets.dtype == torch.float64
    with torch.no_grad():
        expected = source.features_at(model, np.arange(len(train))).reshape(len(train), -1).double()
    torch.testing.assert_close(design[:, :-1], expected, rtol=1e-6, atol=1e-7)  # the last bits depend on the batch
    assert torch.all(design[:, -1] == 1.0)
    forces = torch.from_numpy(train.bin_forces_n) / model.force_scale_n
    assert torch.equal(targets, forces[..., 2].reshape(len(train), -1).double())
    assert unestimated == pytest.approx(float(torch.sum(forces[..., :2].double() ** 2)))
    features, _, _ = least_squares.camera_features(model, source, batch_size=4, dtype=torch.float32)
    assert features.dtype == torch.float32 and torch.equal(features.double(), design[:, :-1])
    with pytest.raises(ValueError, match="no frames"):
        least_squares.camera_features(model, ImageSource(train.subset(np.arange(0)), model.force_scale_n))


def test_least_squares_keeps_the_layer_when_no_ridge_helps(frames, tiny_config):
    model = model_for(frames, tiny_config).eval()
    train, val = splits(frames)
    sources = [CachedSource(model, part, "trunk") for part in (train, val)]
    fit_fusion(model, *sources)
    weights = model.fusion.expand.weight.clone()
    report = fit_fusion(model, *sources, ridges=(1e6,))  # shrinks every weight to ~0: worse than the fit
    assert report["ridge"] is None
    assert torch.equal(model.fusion.expand.weight, weights)


def test_train_phases_run_head_and_fusion_fit_and_resume_in_the_head_phase(frames, tiny_config, tmp_path):
    train, val = splits(frames)
    config = TrainConfig(max_epochs=2, head_epochs=4, batch_size=8, learning_rate=5e-3, seed=1, head_cycles=1)
    straight = model_for(frames, tiny_config)
    results = train_phases(straight, train, val, config)
    assert set(results) == {"end_to_end", "head", "fusion_fit"}
    assert results["head"].epochs_run == 4
    assert all(p.requires_grad for p in straight.parameters())  # the trunk is unfrozen again afterwards

    interrupt_in_head, _ = interrupt_after(4)  # 2 end-to-end epochs, then the 2nd head epoch
    interrupted = model_for(frames, tiny_config)
    with pytest.raises(Interrupt):
        train_phases(interrupted, train, val, config, tmp_path, on_epoch_end=interrupt_in_head)
    assert (tmp_path / "checkpoint_end_to_end.pt").exists() and (tmp_path / "checkpoint_head.pt").exists()
    resumed = model_for(frames, tiny_config)
    train_phases(resumed, train, val, config, tmp_path, resume=True)
    for key, value in straight.state_dict().items():
        assert torch.equal(value, resumed.state_dict()[key]), key


def test_an_interrupted_run_resumes_its_end_to_end_phase_with_new_head_settings(frames, tiny_config, tmp_path):
    """The end-to-end checkpoint is compared on the settings that decide that phase alone, the head checkpoint on
    the head's too: a user can change the head of an interrupted run without training the conv trunk again."""
    train, val = splits(frames)
    config = TrainConfig(max_epochs=2, head_epochs=3, batch_size=8, learning_rate=5e-3, seed=1, head_cycles=1)
    new_head = replace(config, head_epochs=2, head_noise_sigma=0.5)

    interrupt_in_head, _ = interrupt_after(3)  # 2 end-to-end epochs, then the 1st head epoch
    with pytest.raises(Interrupt):
        train_phases(model_for(frames, tiny_config), train, val, config, tmp_path, on_epoch_end=interrupt_in_head)
    with pytest.raises(ValueError, match=r"checkpoint_head\.pt was written with other training settings: "
                                         r"head_epochs 3 \(now 2\), head_noise_sigma 1\.2 \(now 0\.5\);"):
        train_phases(model_for(frames, tiny_config), train, val, new_head, tmp_path, resume=True)
    with pytest.raises(ValueError, match=r"checkpoint_end_to_end\.pt .*: max_epochs 2 \(now 3\);"):
        train_phases(model_for(frames, tiny_config), train, val, replace(config, max_epochs=3), tmp_path, resume=True)

    (tmp_path / "checkpoint_head.pt").unlink()
    count_epochs, calls = interrupt_after(3)
    resumed = model_for(frames, tiny_config)
    results = train_phases(resumed, train, val, new_head, tmp_path, resume=True, on_epoch_end=count_epochs)
    assert calls == [1, 2] and results["end_to_end"].epochs_run == 2  # only the head trained, with its new settings
    straight = model_for(frames, tiny_config)
    train_phases(straight, train, val, new_head)
    for key, value in straight.state_dict().items():
        assert torch.equal(value, resumed.state_dict()[key]), key


def test_a_head_checkpoint_on_top_of_another_conv_trunk_is_refused(frames, tiny_config, tmp_path):
    """The head checkpoint holds the trunk it was trained on: after the end-to-end phase was trained again (its
    checkpoint deleted, other settings), resuming it would put the old trunk under the new trunk's cached features."""
    train, val = splits(frames)
    config = TrainConfig(max_epochs=2, head_epochs=3, batch_size=8, learning_rate=5e-3, seed=1, head_cycles=1)

    interrupt_in_head, _ = interrupt_after(3)  # 2 end-to-end epochs, then the 1st head epoch
    with pytest.raises(Interrupt):
        train_phases(model_for(frames, tiny_config), train, val, config, tmp_path, on_epoch_end=interrupt_in_head)
    # The end-to-end phase trained again gives another trunk; here the head checkpoint's trunk is moved instead, so
    # that the trunks differ for certain (a tiny run may keep its initial weights whatever its settings).
    head_checkpoint = tmp_path / "checkpoint_head.pt"
    saved = torch.load(head_checkpoint, weights_only=False)
    name = next(k for k in saved["model"] if k.startswith("cnn.trunk.") and k.endswith("weight"))
    saved["model"][name] = saved["model"][name] + 0.01
    torch.save(saved, head_checkpoint)
    with pytest.raises(ValueError, match=r"checkpoint_head\.pt was trained on top of other frozen weights than this "
                                         rf"model has \({name}, \.\.\.\)"):
        train_phases(model_for(frames, tiny_config), train, val, config, tmp_path, resume=True)


def test_a_checkpoint_of_other_frames_is_refused(frames, tiny_config, tmp_path):
    """Resuming on other frames (another scene, --frames, dataset) would train one model on two data sets."""
    train, val = splits(frames)
    config = TrainConfig(max_epochs=2, head_epochs=1, batch_size=8, head_cycles=1)

    with pytest.raises(Interrupt):
        train_phases(model_for(frames, tiny_config), train, val, config, tmp_path, on_epoch_end=interrupt_after(1)[0])
    fewer = train.subset(np.arange(len(train) - 1))
    with pytest.raises(ValueError, match=rf"checkpoint_end_to_end\.pt was trained on other data: train_frames "
                                         rf"{len(train)} \(now {len(fewer)}\), targets_sha256 "):
        train_phases(model_for(frames, tiny_config), fewer, val, config, tmp_path, resume=True)
    results = train_phases(model_for(frames, tiny_config), train, val, config, tmp_path, resume=True)
    assert results["end_to_end"].epochs_run == 2  # the same frames resume


@pytest.fixture
def more(make_frames):
    """16 frames of other presses than `frames`, on the same cameras and reference images (the same generator,
    drawn further)."""
    return make_frames(64).subset(np.arange(48, 64))


def test_extra_frames_join_the_head_source_without_a_copy(frames, more, tiny_config):
    train, _ = splits(frames)
    model = model_for(frames, tiny_config).eval()
    augmentation = Augmentation(noise_sigma=4.0)
    source = CachedSource(model, train, "trunk", augmentation=augmentation, seed=2,
                          extra=[more.subset(np.arange(10)), more.subset(np.arange(10, 16))])  # in two chunks
    plain = CachedSource(model, train, "trunk", augmentation=augmentation, seed=2)
    n, m = len(train), len(more)
    assert source.extra_frames == m and len(source) == 2 * n + m
    # The frames, the extra frames, then the copy of the frames alone, drawn as without extra frames.
    assert torch.equal(source.features[:n], plain.features[:n])
    torch.testing.assert_close(source.features[n:n + m], CachedSource(model, more, "trunk").features)
    assert torch.equal(source.features[n + m:], plain.features[n:])
    assert torch.equal(source.target(np.arange(n, n + m)), CachedSource(model, more, "trunk").target(np.arange(m)))
    assert torch.equal(source.target(np.arange(n + m, 2 * n + m)), source.target(np.arange(n)))
    # The least-squares fit gets the frames and the extra frames; a new copy keeps the extra frames' features.
    assert torch.equal(source.frames_only().features, source.features[:n + m])
    extra_features = source.features[n:n + m].clone()
    source.redraw_copy(model, train, augmentation, seed=3)
    assert len(source) == 2 * n + m and torch.equal(source.features[n:n + m], extra_features)
    with pytest.raises(ValueError, match=r"extra frames of cameras \['right', 'left'\]"):
        CachedSource(model, train, "trunk", extra=[more.select_cameras(("right", "left"))])


def test_extra_frames_teach_the_head_alone_and_its_checkpoints_resume_only_on_them(frames, more, tiny_config,
                                                                                    tmp_path):
    train, val = splits(frames)
    config = TrainConfig(max_epochs=1, head_epochs=2, batch_size=8, seed=1, head_cycles=1)
    without, straight = model_for(frames, tiny_config), model_for(frames, tiny_config)
    train_phases(without, train, val, config)
    train_phases(straight, train, val, config, head_extra=[more])
    trunk = [k for k in straight.state_dict() if k.startswith("cnn.trunk.")]
    assert trunk and all(torch.equal(straight.state_dict()[k], without.state_dict()[k]) for k in trunk)
    assert not torch.equal(straight.fusion.expand.weight, without.fusion.expand.weight)

    interrupt_in_head, _ = interrupt_after(2)  # 1 end-to-end epoch, then the 1st head epoch
    with pytest.raises(Interrupt):
        train_phases(model_for(frames, tiny_config), train, val, config, tmp_path, on_epoch_end=interrupt_in_head,
                     head_extra=[more])
    with pytest.raises(ValueError, match=r"checkpoint_head\.pt was trained on other data: head_extra_frames 16 "
                                         r"\(now None\), head_extra_targets_sha256 "):
        train_phases(model_for(frames, tiny_config), train, val, config, tmp_path, resume=True)
    with pytest.raises(ValueError, match=r"checkpoint_head\.pt was trained on other data: head_extra_frames 16 "
                                         r"\(now 15\)"):
        train_phases(model_for(frames, tiny_config), train, val, config, tmp_path, resume=True,
                     head_extra=[more.subset(np.arange(15))])
    resumed = model_for(frames, tiny_config)
    train_phases(resumed, train, val, config, tmp_path, resume=True, head_extra=[more])
    for key, value in straight.state_dict().items():
        assert torch.equal(value, resumed.state_dict()[key]), key


def test_every_training_setting_belongs_to_one_phase_or_none():
    """Resuming compares a phase's own settings: a setting missing from every group would never be compared."""
    groups = END_TO_END_SETTINGS + HEAD_SETTINGS + SHARED_SETTINGS + NOT_PHASE_SETTINGS
    assert sorted(groups) == sorted(f.name for f in fields(TrainConfig))


#: Tests of training on a GPU (`--device cuda`). CI has none; they ran on an NVIDIA H100 (docs/learning.md, Training on
#: a GPU). Everything else about --device (what is refused, and where) is tested on the CPU.
on_a_gpu = pytest.mark.skipif(not torch.cuda.is_available(), reason="needs a CUDA GPU")


@on_a_gpu
def test_training_on_a_gpu_trains_as_on_the_cpu_and_leaves_the_model_there(frames, tiny_config):
    """The same steps on either device, the model back on the CPU. Without dropout: on a GPU its masks come from CUDA's
    generator, so a run with dropout is another draw than the CPU's (docs/learning.md). One head cycle: a second
    one restarts the head from a fit to 34 frames, and its error climbs tenfold on either device, where the differences
    of rounding (cuDNN's TF32 convolutions) grow as fast."""
    train, val = splits(frames)
    config = TrainConfig(max_epochs=3, head_epochs=4, batch_size=8, learning_rate=5e-3, seed=1, head_cycles=1,
                         head_precision="fp32", device="cuda")
    without_dropout = replace(tiny_config, dropout=0.0)
    on_gpu, on_cpu = model_for(frames, without_dropout), model_for(frames, without_dropout)
    devices = []  # where the model was after each epoch: on the GPU, or the option did nothing (review)
    gpu = train_phases(on_gpu, train, val, config, fz_threshold=True,
                       on_epoch_end=lambda epoch, record: devices.append(on_gpu.device.type))
    cpu = train_phases(on_cpu, train, val, replace(config, device="cpu"), fz_threshold=True)
    assert devices == ["cuda"] * 7  # 3 end-to-end epochs and 4 of the head
    assert all(t.device.type == "cpu" for t in [*on_gpu.parameters(), *on_gpu.buffers()])
    for phase in ("end_to_end", "head"):
        assert [r["val_rmse"] for r in gpu[phase].history] == pytest.approx(
            [r["val_rmse"] for r in cpu[phase].history], rel=0.02), phase
    trained_rmse = normalised_rmse(on_gpu, ImageSource(val, on_gpu.force_scale_n))
    assert trained_rmse < 0.8 * gpu["end_to_end"].initial_val_rmse
    # The least-squares fit to 34 frames magnifies the differences: 1e-3 of relative noise on the initial weights moved
    # its result by 1 % on the CPU.
    assert trained_rmse == pytest.approx(normalised_rmse(on_cpu, ImageSource(val, on_cpu.force_scale_n)), rel=0.1)


@on_a_gpu
def test_a_run_interrupted_on_a_gpu_resumes_on_the_cpu(frames, tiny_config, tmp_path):
    train, val = splits(frames)
    # The head's precision named: "auto" resolves per device, and a head checkpoint is compared on what it resolved to
    # (docs/learning.md, Training on a GPU).
    config = TrainConfig(max_epochs=2, head_epochs=3, batch_size=8, learning_rate=5e-3, seed=1, head_cycles=1,
                         head_precision="fp32", device="cuda")
    interrupt_in_head, _ = interrupt_after(3)  # 2 end-to-end epochs, then the 1st head epoch
    interrupted = model_for(frames, tiny_config)
    with pytest.raises(Interrupt):
        train_phases(interrupted, train, val, config, tmp_path, on_epoch_end=interrupt_in_head)
    assert all(p.device.type == "cpu" for p in interrupted.parameters())  # back on the CPU after the interruption
    count_epochs, calls = interrupt_after(99)
    resumed = model_for(frames, tiny_config)
    results = train_phases(resumed, train, val, replace(config, device="cpu"), tmp_path, resume=True,
                           on_epoch_end=count_epochs)
    assert calls == [2, 3] and results["head"].epochs_run == 3  # the head went on where the GPU left it
    assert all(bool(torch.isfinite(p).all()) for p in resumed.parameters())


def test_further_head_cycles_start_from_the_fit_and_resume_exactly(frames, tiny_config, tmp_path):
    train, val = splits(frames)
    config = TrainConfig(max_epochs=1, head_epochs=3, batch_size=8, learning_rate=5e-3, seed=2, head_cycles=2,
                         head_precision="bf16")
    two = model_for(frames, tiny_config)
    results = train_phases(two, train, val, config)
    assert set(results) == {"end_to_end", "head", "fusion_fit", "head_2", "fusion_fit_2"}
    assert results["head_2"].epochs_run == 3
    assert results["head"].kept_epoch == results["head_2"].kept_epoch == 3  # the last epochs, then the fit judged
    assert results["fusion_fit"]["cycle_kept"]
    assert results["fusion_fit"]["val_rmse_after"] < results["end_to_end"].best_val_rmse
    # The second cycle starts where the first one's fit left the model: its initial validation error is the fit's
    # (the fit scores in float64, the model in float32).
    assert results["head_2"].initial_val_rmse == pytest.approx(results["fusion_fit"]["val_rmse_after"], rel=1e-5)

    interrupt_in_the_second_cycle, _ = interrupt_after(6)  # 1 end-to-end epoch, 3 head epochs, 2 of the 2nd cycle
    with pytest.raises(Interrupt):
        train_phases(model_for(frames, tiny_config), train, val, config, tmp_path,
                     on_epoch_end=interrupt_in_the_second_cycle)
    assert (tmp_path / "checkpoint_head_2.pt").exists()
    resumed = model_for(frames, tiny_config)
    train_phases(resumed, train, val, config, tmp_path, resume=True)
    for key, value in two.state_dict().items():
        assert torch.equal(value, resumed.state_dict()[key]), key
    # A later cycle's checkpoint is compared on the head settings too (the first cycle's deleted, so it trains anew).
    (tmp_path / "checkpoint_head.pt").unlink()
    with pytest.raises(ValueError, match=r"checkpoint_head_2\.pt was written with other training settings: "
                                         r"head_noise_sigma 1\.2 \(now 0\.5\);"):
        train_phases(model_for(frames, tiny_config), train, val, replace(config, head_noise_sigma=0.5), tmp_path,
                     resume=True)
    with pytest.raises(ValueError, match="TrainConfig.head_cycles must be a whole number >= 1"):
        TrainConfig(head_cycles=0)


def test_a_head_cycle_that_its_fit_leaves_worse_is_undone(frames, tiny_config):
    """A head learning rate this large saturates the sigmoid features: fitted, the cycle is worse than the end-to-end
    result, so the model goes on from the end-to-end weights."""
    train, val = splits(frames)
    config = TrainConfig(max_epochs=40, patience=40, batch_size=4, learning_rate=1e-2, head_epochs=2,
                         head_learning_rate=1e3, head_cycles=1)
    model = model_for(frames, replace(tiny_config, feature_activation="sigmoid"))
    val_seen, best_end_to_end = [], []

    def snapshot_the_best_end_to_end_epoch(epoch, record):
        val_seen.append(record["val_rmse"])
        if len(val_seen) <= config.max_epochs and record["val_rmse"] == min(val_seen):
            best_end_to_end[:] = [copy.deepcopy(model.state_dict())]

    results = train_phases(model, train, val, config, on_epoch_end=snapshot_the_best_end_to_end_epoch)
    assert results["fusion_fit"]["val_rmse_after"] > results["end_to_end"].best_val_rmse
    assert not results["fusion_fit"]["cycle_kept"]
    for key, value in best_end_to_end[0].items():
        assert torch.equal(value, model.state_dict()[key]), key
    assert normalised_rmse(model, ImageSource(val, model.force_scale_n)) == pytest.approx(
        results["end_to_end"].best_val_rmse, rel=1e-5)


def test_the_fusion_fit_learns_from_the_frames_alone_not_their_imperfect_copy(frames, tiny_config):
    train, val = splits(frames)
    model = model_for(frames, tiny_config)
    config = TrainConfig(max_epochs=1, head_epochs=1, batch_size=8, seed=1, head_cycles=1, head_noise_sigma=8.0)
    results = train_phases(model, train, val, config)
    # The validation score of every ridge depends only on the head's features and the frames fitted.
    fitted_rows = {"frames": CachedSource(model, train, "trunk"),
                   "frames and copy": CachedSource(model, train, "trunk", augmentation=config.head_augmentation(),
                                                   seed=config.seed)}
    scores = {name: fit_fusion(copy.deepcopy(model), rows, CachedSource(model, val, "trunk"))["val_rmse"]
              for name, rows in fitted_rows.items()}
    assert scores["frames"] == pytest.approx(results["fusion_fit"]["val_rmse"], rel=1e-9)
    assert scores["frames and copy"] != pytest.approx(results["fusion_fit"]["val_rmse"], rel=1e-6)


def test_head_steps_in_bf16_train_another_head_on_the_same_trunk_and_say_so(frames, tiny_config):
    """bf16 rounds the forward pass of the head's steps only: the end-to-end phase before it is the same, the head
    comes out otherwise, and it still learns (its validation error, computed in float32, falls)."""
    train, val = splits(frames)
    models, results = {}, {}
    for precision in ("fp32", "bf16"):
        models[precision] = model_for(frames, tiny_config)
        config = TrainConfig(max_epochs=1, head_epochs=3, batch_size=8, head_cycles=1, head_precision=precision)
        results[precision] = train_phases(models[precision], train, val, config)
    for precision, result in results.items():
        assert result["end_to_end"].step_precision == "fp32"
        assert result["head"].step_precision == precision
        assert result["head"].best_val_rmse < result["head"].initial_val_rmse
        assert all(np.isfinite(r["val_rmse"]) for r in result["head"].history)
    fp32, bf16 = (dict(models[p].named_parameters()) for p in ("fp32", "bf16"))
    assert all(torch.equal(fp32[k], bf16[k]) for k in fp32 if k.startswith("cnn.trunk."))
    assert not torch.equal(fp32["cnn.last_layer.linear.weight"], bf16["cnn.last_layer.linear.weight"])


def test_bf16_steps_leave_validation_in_float32(frames, tiny_config, monkeypatch):
    """Only the training steps' predictions come out in bf16; those that choose the best epoch are float32."""
    seen = set()
    predict = CachedSource.predict

    def recording(self, model, indices):
        prediction = predict(self, model, indices)
        seen.add((model.training, prediction.dtype))
        return prediction

    monkeypatch.setattr(CachedSource, "predict", recording)
    train, val = splits(frames)
    train_phases(model_for(frames, tiny_config), train, val,
                 TrainConfig(max_epochs=1, head_epochs=1, batch_size=8, head_cycles=1, head_precision="bf16"))
    assert seen == {(True, torch.bfloat16), (False, torch.float32)}


def test_each_phase_trains_at_its_own_dropout_rate_and_restores_the_models(frames, tiny_config):
    train, val = splits(frames)
    model = model_for(frames, tiny_config)
    rates = []

    def record_rates(epoch, record):
        rates.append((model.cnn.first_layer.dropout.p, model.cnn.last_layer.dropout.p))

    config = TrainConfig(max_epochs=1, head_epochs=2, batch_size=8, end_to_end_dropout=0.4, head_dropout=0.3,
                         head_cycles=1)
    train_phases(model, train, val, config, on_epoch_end=record_rates)
    assert rates == [(0.4, 0.4), (0.3, 0.3), (0.3, 0.3)]
    train_phases(model, train, val, replace(config, end_to_end_dropout=None, head_dropout=None),
                 on_epoch_end=record_rates)
    assert rates[3:] == [(0.1, 0.1)] * 3  # None: the model's rate throughout
    assert model.cnn.set_dropout(0.2) == 0.1  # restored after the phase
    defaults = replace(TrainConfig(), max_epochs=1, head_epochs=2, batch_size=8)
    train_phases(model, train, val, defaults, on_epoch_end=record_rates)
    # The default: no dropout in any phase (the head phase in all its cycles) ...
    assert rates[6:] == [(0.0, 0.0)] * (1 + 2 * defaults.head_cycles)
    assert defaults.head_augmentation().active  # ... whose head also learns from an imperfect copy of the frames

    def interrupt_in(rate):
        def interrupt(epoch, record):
            if model.cnn.first_layer.dropout.p == rate:
                raise KeyboardInterrupt
        return interrupt

    for rate in (0.4, 0.3):  # ... and when a phase is interrupted
        with pytest.raises(KeyboardInterrupt):
            train_phases(model, train, val, config, on_epoch_end=interrupt_in(rate))
        assert model.cnn.first_layer.dropout.p == model.cnn.last_layer.dropout.p == 0.2
    with pytest.raises(ValueError, match="rate must be in"):
        model.cnn.set_dropout(1.0)
    for name in ("end_to_end_dropout", "head_dropout"):
        with pytest.raises(ValueError, match=name):
            TrainConfig(**{name: -0.1})


def test_augmented_noise_draws_one_seeded_sigma_per_frame_and_stays_in_uint8():
    images = np.full((40, 2, 32, 32), 128, np.uint8)
    images[0] = 0
    images[1] = 255
    noise = Augmentation(noise_sigma=3.0)
    noisy = noise.apply(images, np.random.default_rng(4))
    assert noisy.dtype == np.uint8 and noisy.shape == images.shape
    np.testing.assert_array_equal(noisy, noise.apply(images, np.random.default_rng(4)))
    spread = (noisy[2:].astype(float) - 128).std(axis=(1, 2, 3))
    assert spread.max() < 3.2 and spread.min() < 1.0 < 2.0 < spread.max()  # sigmas spread over [0, 3]
    assert 0 < noisy[0].max() < 64 and 192 < noisy[1].min() < 255  # clipped at the ends, not wrapped
    assert not Augmentation().active
    # Blur first, then noise (the sensor's noise is not blurred): on flat frames the noise stays white, neighbouring
    # pixels differing by about 1.13 sigma (2 / sqrt(pi)); blurred after, they would differ far less.
    both = Augmentation(noise_sigma=3.0, blur_fraction=1.0, blur_sigma_px=2.0).apply(images[2:],
                                                                                     np.random.default_rng(4))
    deviation = both.astype(float) - 128
    strong = deviation.std(axis=(1, 2, 3)) > 1.5
    steps = np.abs(np.diff(deviation, axis=-1)).mean(axis=(1, 2, 3))
    assert strong.sum() > 10 and np.all(steps[strong] > 0.9 * deviation.std(axis=(1, 2, 3))[strong])
    np.testing.assert_array_equal(Augmentation().apply(images, np.random.default_rng(4)), images)


def test_augmented_blur_defocuses_the_asked_share_of_frames_only():
    images = np.random.default_rng(0).integers(0, 256, (200, 2, 24, 24), dtype=np.uint8)
    blur = Augmentation(blur_fraction=0.3, blur_sigma_px=2.0)
    blurred = blur.apply(images, np.random.default_rng(5))
    np.testing.assert_array_equal(blurred, blur.apply(images, np.random.default_rng(5)))
    changed = np.any(blurred != images, axis=(1, 2, 3))
    assert 40 < changed.sum() < 80  # about 30 % of 200 frames

    def roughness(frames):
        return np.abs(np.diff(frames.astype(float), axis=-1)).mean(axis=(1, 2, 3))

    assert np.all(roughness(blurred[changed]) < roughness(images[changed]))  # blur smooths every changed frame ...
    assert np.median(roughness(blurred[changed])) < 0.5 * np.median(roughness(images))  # ... most of them clearly
    assert np.all(np.any(Augmentation(blur_fraction=1.0).apply(images, np.random.default_rng(5)) != images,
                         axis=(1, 2, 3)))
    for field, bad in (("noise_sigma", -1.0), ("noise_sigma", float("nan")), ("blur_fraction", 1.5),
                       ("blur_sigma_px", 0.1)):
        with pytest.raises(ValueError, match=f"Augmentation.{field} must be"):
            Augmentation(**{field: bad})


def test_augmented_misalignment_knocks_one_camera_askew_in_the_asked_share_of_frames():
    images = np.random.default_rng(0).integers(0, 256, (200, 3, 24, 24), dtype=np.uint8)
    askew = Augmentation(misalign_fraction=0.3)
    moved = askew.apply(images, np.random.default_rng(6))
    assert askew.active
    np.testing.assert_array_equal(moved, askew.apply(images, np.random.default_rng(6)))
    changed = np.any(moved != images, axis=(2, 3))                       # (frames, cameras)
    assert 40 < changed.any(axis=1).sum() < 80 and changed.sum(axis=1).max() == 1  # about 30 %, one camera each
    assert len(set(np.flatnonzero(changed) % 3)) == 3                    # any camera can be the one
    # The change is the warp alone: a camera knocked by nothing stays as it was, pixel for pixel.
    still = Augmentation(misalign_fraction=1.0, misalign_shift_px=0.0, misalign_rotation_deg=0.0)
    np.testing.assert_array_equal(still.apply(images, np.random.default_rng(6)), images)
    for field, bad in (("misalign_fraction", -0.1), ("misalign_shift_px", 20.0), ("misalign_rotation_deg", -1.0)):
        with pytest.raises(ValueError, match=f"Augmentation.{field} must be"):
            Augmentation(**{field: bad})
    with pytest.raises(ValueError, match="TrainConfig.head_misalign_fraction must be"):
        TrainConfig(head_misalign_fraction=2.0)
    with pytest.raises(ValueError, match="TrainConfig.head_misalign_rotation_deg must be"):
        TrainConfig(head_misalign_rotation_deg=50.0)
    # The shift and rotation are training settings (recorded in training.json and checkpoints), not hidden defaults.
    wider = TrainConfig(head_misalign_shift_px=3.0, head_misalign_rotation_deg=4.0).head_augmentation()
    assert (wider.misalign_shift_px, wider.misalign_rotation_deg) == (3.0, 4.0)


def test_the_head_phase_also_learns_from_an_imperfect_copy_of_the_frames(frames, tiny_config, monkeypatch):
    train, val = splits(frames)
    model = model_for(frames, tiny_config).eval()
    clean = CachedSource(model, train, "trunk")
    augmentation = Augmentation(noise_sigma=4.0, blur_fraction=0.5)
    both = CachedSource(model, train, "trunk", augmentation=augmentation, seed=2)
    n = len(clean)
    assert len(both) == 2 * n
    assert torch.equal(both.features[:n], clean.features) and not torch.equal(both.features[n:], clean.features)
    assert torch.equal(both.target(np.arange(2 * n)), torch.cat([clean.target(np.arange(n))] * 2))
    torch.testing.assert_close(CachedSource(model, train, "trunk", augmentation=augmentation, seed=2).features,
                               both.features, rtol=0, atol=0)
    # A redrawn copy is the copy a new source with that seed would hold; the frames' own features stay.
    redrawn = CachedSource(model, train, "trunk", augmentation=augmentation, seed=2)
    cache = redrawn.features.data_ptr()
    redrawn.redraw_copy(model, train, augmentation, seed=3)
    torch.testing.assert_close(redrawn.features, CachedSource(model, train, "trunk", augmentation=augmentation,
                                                              seed=3).features, rtol=0, atol=0)
    assert not torch.equal(redrawn.features[n:], both.features[n:])
    assert redrawn.features.data_ptr() == cache  # redrawn in place: the cache is never held twice
    redrawn.redraw_copy(model, train, None, seed=3)
    assert torch.equal(redrawn.features, clean.features)
    # A source built without a copy gets room for one.
    grown = CachedSource(model, train, "trunk")
    grown.redraw_copy(model, train, augmentation, seed=2)
    assert torch.equal(grown.features, both.features)
    # Frame i's copy is drawn from (seed, i) alone, whatever frames share its forward batch.
    assert n % 5 and n > 5 and sources.FRONT_BATCH_FRAMES != 5
    monkeypatch.setattr(sources, "FRONT_BATCH_FRAMES", 5)
    torch.testing.assert_close(CachedSource(model, train, "trunk", augmentation=augmentation, seed=2).features,
                               both.features)
    monkeypatch.undo()
    frames_only = both.frames_only()
    assert len(frames_only) == n and torch.equal(frames_only.features, clean.features) and len(both) == 2 * n

    config = TrainConfig(max_epochs=1, head_epochs=2, batch_size=8, seed=1)
    plain_config = replace(config, head_noise_sigma=0.0, head_blur_fraction=0.0, head_misalign_fraction=0.0)
    trained = []
    for settings in (plain_config, config, config):
        model = model_for(frames, tiny_config)
        train_phases(model, train, val, settings)
        trained.append(model.state_dict())
    plain, first, second = trained
    for key in plain:
        assert torch.equal(first[key], second[key]), key  # seeded
    assert torch.equal(plain["cnn.trunk.0.conv.weight"], first["cnn.trunk.0.conv.weight"])  # end to end unchanged
    assert not torch.equal(plain["cnn.last_layer.linear.weight"], first["cnn.last_layer.linear.weight"])
    for bad in ({"head_noise_sigma": -1.0}, {"head_noise_sigma": float("nan")}, {"head_blur_fraction": 2.0},
                {"head_blur_sigma_px": 0.0}):
        with pytest.raises(ValueError, match=f"TrainConfig.{next(iter(bad))} must be"):
            TrainConfig(**bad)


def test_filling_a_cache_keeps_the_callers_torch_threads_and_draws_the_same_copy_at_any_count(frames, tiny_config,
                                                                                             monkeypatch):
    """A cache is filled with torch on one thread (its busy-waiting pool took a core from ONNX Runtime's,
    CachedSource._front); the caller's count comes back, also when filling fails, and the features and copy are the
    same to the bit whatever count the caller runs at."""
    train, _ = splits(frames)
    model = model_for(frames, tiny_config).eval()
    augmentation = Augmentation(noise_sigma=4.0, blur_fraction=0.5, misalign_fraction=0.5)
    session_threads = []
    session = sources.onnx_session
    monkeypatch.setattr(sources, "onnx_session", lambda graph, threads: session_threads.append(threads) or
                        session(graph, threads))
    filled = {}
    for threads in (2, 1):
        torch.set_num_threads(threads)
        filled[threads] = CachedSource(model, train, "trunk", augmentation=augmentation, seed=2).features
        assert torch.get_num_threads() == threads
        assert set(session_threads) == {threads}  # ONNX Runtime runs at the caller's count, torch at one
        session_threads.clear()
    assert torch.equal(filled[1], filled[2])

    def broken(*_):
        assert torch.get_num_threads() == 1  # the changes to the copy's images run on torch's one thread
        raise RuntimeError("camera imperfection failed")

    torch.set_num_threads(2)
    monkeypatch.setattr(Augmentation, "apply_each", broken)
    with pytest.raises(RuntimeError, match="camera imperfection failed"):
        CachedSource(model, train, "trunk", augmentation=augmentation, seed=2)
    assert torch.get_num_threads() == 2


def test_added_camera_starts_from_the_base_prediction_and_only_the_last_layers_train(frames, tiny_config):
    base_frames = frames.select_cameras(("left",))
    train, val = splits(base_frames)
    base = model_for(base_frames, tiny_config)
    fit(base, ImageSource(train, base.force_scale_n), ImageSource(val, base.force_scale_n),
        TrainConfig(max_epochs=2, batch_size=8))
    grown = add_camera(base, ("left", "right"))
    np.testing.assert_allclose(predict_torch(grown, frames), predict_torch(base, base_frames), atol=1e-6)
    fz_base = model_for(base_frames, tiny_config, components=("fz",)).eval()
    fz_grown = add_camera(fz_base, ("left", "right"))
    assert fz_grown.components == ("fz",)
    np.testing.assert_allclose(predict_torch(fz_grown, frames), predict_torch(fz_base, base_frames), atol=1e-6)
    fz_base.fz_threshold_n = float(np.median(predict_torch(fz_base, base_frames)[..., 2]))  # acts on half the bins
    thresholded = add_camera(fz_base, ("left", "right"))
    assert thresholded.fz_threshold_n == fz_base.fz_threshold_n
    np.testing.assert_allclose(predict_torch(thresholded, frames), predict_torch(fz_base, base_frames), atol=1e-6)
    trainable = {name for name, p in grown.named_parameters() if p.requires_grad}
    assert trainable and all(n.startswith(("cnn.last_layer", "fusion")) for n in trainable)

    full_train, full_val = splits(frames)
    frozen = {k: v.clone() for k, v in grown.state_dict().items() if k.startswith(("cnn.trunk", "cnn.first_layer"))}
    config = TrainConfig(max_epochs=1, batch_size=8, head_batch_size=8, recalibration_epochs=3)
    model, result, wall_s = recalibrate(base, full_train, full_val, config)
    assert wall_s > 0 and result.epochs_run == 3
    assert result.kept_epoch == 3  # the trained layers, fitted, beat the start with only its fusion fitted
    assert result.step_precision == config.recalibration_phase().head_precision
    for key, value in frozen.items():
        assert torch.equal(model.state_dict()[key], value), f"{key} changed during recalibration"
    assert not torch.equal(model.state_dict()["cnn.last_layer.linear.weight"],
                           grown.state_dict()["cnn.last_layer.linear.weight"])
    # Recalibration trains at the head phase's dropout (None: the model's own), and leaves the model's rate as it was.
    at_model_rate, _, _ = recalibrate(base, full_train, full_val, replace(config, head_dropout=None))
    at_that_rate, _, _ = recalibrate(base, full_train, full_val, replace(config, head_dropout=0.1))
    at_half, _, _ = recalibrate(base, full_train, full_val, replace(config, head_dropout=0.5))
    weight = "cnn.last_layer.linear.weight"
    assert torch.equal(at_model_rate.state_dict()[weight], at_that_rate.state_dict()[weight])
    assert not torch.equal(at_model_rate.state_dict()[weight], at_half.state_dict()[weight])
    assert not torch.equal(model.state_dict()[weight], at_half.state_dict()[weight])  # the default, 0
    assert at_half.cnn.last_layer.dropout.p == at_half.cnn.first_layer.dropout.p == base.config.dropout == 0.1
    # A learning rate this large, with dropout, wrecks the last layer: the start with only its fusion fitted is kept.
    wrecked, result, _ = recalibrate(base, full_train, full_val,
                                     replace(config, head_learning_rate=1e4, head_dropout=None))
    assert result.kept_epoch == 0
    start = add_camera(base, ("left", "right"))
    fitted = fit_fusion(start, CachedSource(start, full_train, "hidden"), CachedSource(start, full_val, "hidden"))
    assert fitted["ridge"] is not None  # the fit changed the start
    for key, value in start.state_dict().items():
        assert torch.equal(wrecked.state_dict()[key], value), key
    # One so large that the layers diverge to NaN: the start is kept as well (NaN compared False, and the NaN weights
    # were returned).
    diverged, result, _ = recalibrate(base, full_train, full_val,
                                      replace(config, head_learning_rate=1e30, head_precision="fp32"))
    assert np.isnan(result.history[-1]["val_rmse"]) and result.kept_epoch == 0
    assert all(torch.equal(diverged.state_dict()[key], value) for key, value in start.state_dict().items())
    with pytest.raises(ValueError, match="at least one more"):
        add_camera(base, ("left",))


def test_a_camera_is_added_where_the_fusion_rank_makes_the_base_dense_and_the_new_layer_factored():
    """Rank 35 with 10 features per camera and 64 outputs: the 3-camera base's fusion layer (30 inputs) is dense, the
    4-camera model's (40 inputs) factored. The new layer starts as the base's map, exactly, and both of its matrices
    train."""
    config = ModelConfig(image_size=16, conv_channels=(4, 4), hidden_features=16, camera_features=10, fusion_rank=35)
    torch.manual_seed(0)
    base = ForceFusionNet(config, ("a", "b", "c"), 8, 8, components=("fz",)).eval()
    with torch.no_grad():
        base.fusion.expand.bias.normal_()  # a base whose map is not almost zero
    grown = add_camera(base, ("b", "d", "a", "c"))
    assert base.fusion.reduce is None and grown.fusion.reduce is not None
    rng = np.random.default_rng(0)
    frames = FrameSet(images=rng.integers(0, 256, (5, 4, 16, 16), dtype=np.uint8),
                      bin_forces_n=np.zeros((5, 8, 8, 3), dtype=np.float32),
                      reference=rng.integers(0, 256, (4, 16, 16), dtype=np.uint8),
                      camera_ok=np.ones((5, 4), dtype=bool), camera_ids=("b", "d", "a", "c"))
    before = predict_torch(base, frames.select_cameras(("a", "b", "c")))
    np.testing.assert_allclose(predict_torch(grown, frames), before, atol=1e-6)
    grown.train()
    grown(torch.from_numpy(frames.images), torch.from_numpy(frames.reference))[..., 2].sum().backward()
    assert all(float(layer.weight.grad.abs().sum()) > 0 for layer in (grown.fusion.reduce, grown.fusion.expand))


def test_training_refuses_non_finite_targets_before_it_trains(frames, tiny_config):
    train, val = splits(frames)
    broken = val.subset(np.arange(len(val)))
    broken.bin_forces_n[2, 1, 1, 2] = np.nan
    model = model_for(frames, tiny_config)
    before = copy.deepcopy(model.state_dict())
    with pytest.raises(FrameDataError, match="validation frames of synthetic .* NaN or Inf forces, first in frame 2"):
        train_phases(model, train, broken, TrainConfig(max_epochs=1, batch_size=8, head_epochs=1))
    with pytest.raises(FrameDataError, match="training frames"):
        train_model(broken, val, tiny_config, TrainConfig(max_epochs=1, batch_size=8), None, False, False)
    with pytest.raises(FrameDataError, match="validation frames"):
        recalibrate(model_for(frames.select_cameras(("left",)), tiny_config), train, broken,
                    TrainConfig(max_epochs=1, batch_size=8, head_batch_size=8))
    assert all(torch.equal(before[k], v) for k, v in model.state_dict().items())


def test_without_a_head_phase_there_is_no_imperfect_copy_and_one_fit(frames, tiny_config, monkeypatch):
    """With --head-epochs 0 each head cycle would be the same fit again, and nothing would learn from the copy."""
    def no_copy(*args, **kwargs):
        raise AssertionError("an imperfect copy was drawn without a head phase")

    monkeypatch.setattr(Augmentation, "apply_each", no_copy)
    results = train_phases(model_for(frames, tiny_config), *splits(frames),
                           TrainConfig(max_epochs=1, batch_size=8, head_epochs=0, head_cycles=3))
    assert set(results) == {"end_to_end", "fusion_fit"}


def test_training_leaves_out_the_components_the_training_forces_never_excite(frames, tiny_config):
    vertical = frames.subset(np.arange(len(frames)))
    vertical.bin_forces_n[..., :2] = 0.0  # presses without shear
    config = TrainConfig(max_epochs=1, batch_size=8, head_epochs=1)
    model, _ = train_model(*splits(vertical), tiny_config, config, None, False, False)
    assert model.components == ("fz",) and model.fusion.expand.out_features == 3 * 4
    assert np.all(predict_torch(model, vertical)[..., :2] == 0.0)
    assert train_model(*splits(frames), tiny_config, config, None, False, False)[0].components == ("fx", "fy", "fz")


def test_fraction_subsets_are_nested_and_seeded(frames):
    small, large = fraction_subset(frames, 0.25, seed=1), fraction_subset(frames, 0.5, seed=1)
    assert len(small) == 12 and len(large) == 24
    assert {bytes(i) for i in small.images} <= {bytes(i) for i in large.images}
    with pytest.raises(ValueError, match="fraction"):
        fraction_subset(frames, 0.0, seed=1)
    assert checked_fractions(["0.5", 0.1, 1]) == [0.1, 0.5, 1.0]
    for bad in ([], [0.5, 1.5], [float("nan")], ["x"]):
        with pytest.raises(ValueError):
            checked_fractions(bad)


def constant_fz_model(tiny_config, frames, fz_n: float, components=("fx", "fy", "fz")) -> ForceFusionNet:
    """A model for `frames` that answers every frame with `fz_n` newtons of Fz in every bin (and no Fx, Fy)."""
    scale = torch.tensor([0.01, 0.01, 0.05])
    model = ForceFusionNet(tiny_config, frames.camera_ids, 3, 4, scale, components).eval()
    with torch.no_grad():
        model.fusion.expand.weight.zero_()
        bias = torch.zeros(3, 4, len(components))
        if "fz" in components:
            bias[..., components.index("fz")] = fz_n / 0.05
        model.fusion.expand.bias.copy_(bias.reshape(-1))
    return model


def images_of(model, frames) -> ImageSource:
    """`frames` as the training loop sees them through the whole network."""
    return ImageSource(frames, model.force_scale_n)


def at_rest(frames):
    """The frames with no force at all (as the scenes' rest frames)."""
    return replace(frames, bin_forces_n=np.zeros_like(frames.bin_forces_n))


def test_the_fz_threshold_is_the_smallest_candidate_that_removes_a_spurious_force(tiny_config, frames):
    model = constant_fz_model(tiny_config, frames, 0.0038)
    report = fit_fz_threshold(model, images_of(model, at_rest(frames)))
    # Candidates are 0.01 x the Fz scale (0.5 mN) apart: 3.8 mN of spurious Fz everywhere needs 8 steps of them.
    assert model.fz_threshold_n == pytest.approx(0.004) and report["fz_threshold_n"] == model.fz_threshold_n
    assert report["val_rmse_bin_fz_n"]["none"] == pytest.approx(0.0038)
    assert report["val_rmse_bin_fz_n"]["0.0035"] == pytest.approx(0.0003)
    assert report["val_rmse_bin_fz_n"]["0.004"] == 0.0 and report["val_rmse_total_fz_n"]["0.004"] == 0.0
    assert report["val_rmse_total_fz_n"]["none"] == pytest.approx(12 * 0.0038)
    assert np.all(predict_torch(model, frames)[..., 2] == 0.0)


def test_no_fz_threshold_when_none_beats_the_model_as_it_is(tiny_config, frames):
    """An exact model keeps no threshold (a tie goes to none); so does a model that does not estimate Fz."""
    model = constant_fz_model(tiny_config, frames, 0.0)
    model.fz_threshold_n = 0.01
    assert fit_fz_threshold(model, images_of(model, at_rest(frames)))["fz_threshold_n"] is None
    assert model.fz_threshold_n is None
    no_fz = constant_fz_model(tiny_config, frames, 0.0, ("fx", "fy"))
    assert fit_fz_threshold(no_fz, images_of(no_fz, frames)) == {"fz_threshold_n": None, "val_rmse_bin_fz_n": {},
                                                                 "val_rmse_total_fz_n": {}}


def test_a_threshold_fit_that_fails_leaves_the_models_threshold(tiny_config, frames):
    """It was set to None before the validation frames went through the model, and stayed None (found in review)."""
    model = constant_fz_model(tiny_config, frames, 0.0038)
    model.fz_threshold_n = 0.005
    source = images_of(model, frames)

    def broken(*_):
        raise OSError("a disk error while the validation frames are read")

    source.predict = broken
    with pytest.raises(OSError, match="a disk error"):
        fit_fz_threshold(model, source)
    assert model.fz_threshold_n == 0.005


def fitted_with_threshold(frames, tiny_config, threshold_n: float, ridge: float = 1e-9):
    """(A model whose fusion layer is the plain least-squares fit on the training frames, with an Fz threshold
    set; the training and validation frames; their cached sources)."""
    model = model_for(frames, tiny_config).eval()
    train, val = splits(frames)
    cached = [CachedSource(model, part, "trunk") for part in (train, val)]
    fit_fusion(model, *cached, ridges=(ridge,))
    model.fz_threshold_n = threshold_n
    return model, train, val, cached


def thresholded_fz_sse(model, frames) -> float:
    """Sum of squared errors of the model's (thresholded) Fz on `frames`, newtons squared."""
    return float(np.sum((predict_torch(model, frames)[..., 2].astype(np.float64) - frames.bin_forces_n[..., 2]) ** 2))


def refit_objective(model, frames) -> float:
    """The refit's H on `frames` (least_squares.fit_fusion_under_threshold), newtons squared: (Fz - t - y)^2 on loaded
    bins, max(Fz - t, 0)^2 on the others, Fz before the threshold."""
    threshold, model.fz_threshold_n = model.fz_threshold_n, None
    fz = predict_torch(model, frames)[..., 2].astype(np.float64) - threshold
    model.fz_threshold_n = threshold
    true = frames.bin_forces_n[..., 2]
    return float(np.sum(np.where(true > 0, fz - true, np.maximum(fz, 0.0)) ** 2))


def test_the_fusion_refit_under_the_threshold_never_raises_its_objective_and_leaves_fx_fy_as_fitted(frames,
                                                                                                  tiny_config):
    """Majorisation-minimisation: each iteration's least-squares problem lies above H and touches it at the current
    weights, so H on the training frames cannot rise from one iteration to the next (the ridge is negligible here);
    Fx and Fy are not thresholded, so their weights stay the plain fit's."""
    start, train, _, (cached_train, _) = fitted_with_threshold(frames, tiny_config, threshold_n=0.01)
    errors = []
    for iterations in (0, 1, 2, 4, 8):
        model = copy.deepcopy(start)
        assert fit_fusion_under_threshold(model, cached_train, 1e-9, iterations)
        errors.append(refit_objective(model, train))
    assert all(b <= a * (1 + 1e-5) for a, b in zip(errors, errors[1:], strict=False)), errors
    assert errors[-1] < 0.9 * errors[0], errors  # and the plain fit is not H's optimum
    weights = model.fusion.expand.weight.reshape(3, 4, 3, -1)  # (rows, cols, components, features)
    plain = start.fusion.expand.weight.reshape(3, 4, 3, -1)
    torch.testing.assert_close(weights[:, :, :2], plain[:, :, :2], rtol=1e-4, atol=1e-5)
    assert not torch.allclose(weights[:, :, 2], plain[:, :, 2], rtol=1e-4, atol=1e-5)


def test_the_fusion_refit_finds_a_thresholded_linear_map_of_the_features_exactly(frames, tiny_config):
    """Forces that are max(linear map of the model's own features - t, 0) for the model's t are reached exactly (the
    loaded bins' targets are the forces plus t), where the plain least-squares fit is far off."""
    model = model_for(frames, tiny_config).eval()
    train, val = splits(frames)
    teacher = model_for(frames, tiny_config, seed=1).eval()
    teacher.cnn.load_state_dict(model.cnn.state_dict())
    teacher.fz_threshold_n = float(np.quantile(predict_torch(teacher, train)[..., 2], 0.75))  # a quarter loaded
    train.bin_forces_n[...] = predict_torch(teacher, train)
    cached_train = CachedSource(model, train, "trunk")
    fit_fusion(model, cached_train, CachedSource(model, val, "trunk"), ridges=(1e-9,))
    model.fz_threshold_n = teacher.fz_threshold_n
    plain = thresholded_fz_sse(model, train)
    fit_fusion_under_threshold(model, cached_train, 1e-9, 5)
    assert thresholded_fz_sse(model, train) < 1e-6 * plain


def test_the_fusion_refit_in_chunks_of_frames_is_the_refit_in_one(frames, tiny_config, monkeypatch):
    start, _, _, (cached_train, _) = fitted_with_threshold(frames, tiny_config, threshold_n=0.01)
    whole, chunked = copy.deepcopy(start), copy.deepcopy(start)
    fit_fusion_under_threshold(whole, cached_train, 1e-6, 3)
    monkeypatch.setattr(least_squares, "REFIT_CHUNK_FRAMES", 5)  # 33 training frames: 7 chunks, the last of 3
    fit_fusion_under_threshold(chunked, cached_train, 1e-6, 3)
    torch.testing.assert_close(chunked.fusion.expand.weight, whole.fusion.expand.weight, rtol=1e-5, atol=1e-6)
    torch.testing.assert_close(chunked.fusion.expand.bias, whole.fusion.expand.bias, rtol=1e-5, atol=1e-6)
    assert not torch.equal(whole.fusion.expand.weight, start.fusion.expand.weight)


def test_the_fusion_refit_needs_a_threshold_and_a_dense_fusion_layer(frames, tiny_config):
    model, _, _, (cached_train, _) = fitted_with_threshold(frames, tiny_config, threshold_n=0.01)
    model.fz_threshold_n = None
    with pytest.raises(ValueError, match="no Fz threshold"):
        fit_fusion_under_threshold(model, cached_train, 1e-9, 2)
    factored = model_for(frames, replace(tiny_config, fusion_rank=2))
    factored.fz_threshold_n = 0.01
    with pytest.raises(ValueError, match="only a dense fusion layer"):
        fit_fusion_under_threshold(factored, cached_train, 1e-9, 2)


def test_a_singular_normal_matrix_leaves_the_fusion_layer_as_it_was(frames, tiny_config):
    """Five frames for 25 unknowns per output and no ridge: no Cholesky factor, so no refit, and training goes on with
    the plain fit (recorded as skipped) instead of failing at its very end."""
    model, train, val, _ = fitted_with_threshold(frames, tiny_config, threshold_n=None, ridge=1e-6)
    few = CachedSource(model, train.subset(np.arange(5)), "trunk")
    model.fz_threshold_n = 0.01
    weights = copy.deepcopy(model.fusion.state_dict())
    assert fit_fusion_under_threshold(model, few, 0.0, 3) is False
    assert all(torch.equal(value, weights[name]) for name, value in model.fusion.state_dict().items())
    model.fz_threshold_n = None
    report = fit_threshold_and_fusion(model, few, images_of(model, val), ridge=0.0)
    assert report["fusion_refit"] == {"kept": False, "skipped": "the features' normal matrix is singular at this ridge"}
    assert report["fz_threshold"]["fz_threshold_n"] == model.fz_threshold_n
    assert all(torch.equal(value, weights[name]) for name, value in model.fusion.state_dict().items())


def test_the_threshold_is_chosen_again_for_the_refitted_fusion_layer(frames, tiny_config):
    model, train, val, (cached_train, cached_val) = fitted_with_threshold(frames, tiny_config, threshold_n=None,
                                                                          ridge=1e-6)
    plain = copy.deepcopy(model)
    report = fit_threshold_and_fusion(model, cached_train, cached_val, ridge=1e-6)
    refit = report["fusion_refit"]
    first = fit_fz_threshold(plain, images_of(plain, val))  # from the images: the same as from the cached trunk
    assert refit["kept"] and refit["threshold_before_n"] == first["fz_threshold_n"] is not None
    assert refit["val_rmse_bin_fz_before_n"] == pytest.approx(min(first["val_rmse_bin_fz_n"].values()))
    assert refit["val_rmse_bin_fz_after_n"] < refit["val_rmse_bin_fz_before_n"]
    # The report that applies is the second choice, the model's threshold, and it measures the model as it is.
    assert report["fz_threshold"]["fz_threshold_n"] == model.fz_threshold_n
    fz_error = np.sqrt(np.mean((predict_torch(model, val)[..., 2] - val.bin_forces_n[..., 2]) ** 2))
    assert fz_error == pytest.approx(refit["val_rmse_bin_fz_after_n"], rel=1e-4)


def test_a_refit_that_does_not_beat_the_first_threshold_is_undone(frames, tiny_config):
    """At rest the first threshold removes a constant spurious force exactly; no refit can beat an exact model, so
    the layer and the threshold stay as they were."""
    model = constant_fz_model(tiny_config, frames, 0.0038)
    train, val = splits(frames)
    weights = copy.deepcopy(model.fusion.state_dict())
    report = fit_threshold_and_fusion(model, CachedSource(model, train, "trunk"), images_of(model, at_rest(val)),
                                      ridge=1e-3)
    assert report["fusion_refit"]["kept"] is False and report["fusion_refit"]["val_rmse_bin_fz_before_n"] == 0.0
    assert model.fz_threshold_n == pytest.approx(0.004) == report["fz_threshold"]["fz_threshold_n"]
    for name, value in model.fusion.state_dict().items():
        assert torch.equal(value, weights[name]), name
    # Nothing to refit for: no threshold wins, or the layer is rank-limited.
    exact = constant_fz_model(tiny_config, frames, 0.0)
    report = fit_threshold_and_fusion(exact, CachedSource(exact, train, "trunk"), images_of(exact, at_rest(val)), 1e-3)
    assert report["fusion_refit"] == {"kept": False, "skipped": "no Fz threshold"}
    factored = constant_fz_model(replace(tiny_config, fusion_rank=2), frames, 0.0038)
    report = fit_threshold_and_fusion(factored, CachedSource(factored, train, "trunk"),
                                      images_of(factored, at_rest(val)), 1e-3)
    assert report["fz_threshold"]["fz_threshold_n"] == pytest.approx(0.004) == factored.fz_threshold_n
    assert report["fusion_refit"] == {"kept": False, "skipped": "a rank-limited fusion layer"}


def test_train_and_export_writes_the_chosen_fz_threshold_into_model_json_and_every_graph(tmp_path, make_frames,
                                                                                        tiny_config):
    frames = make_frames(60, seed=5)
    split = split_indices(len(frames), seed=3)
    parts = {name: frames.subset(split[name]) for name in ("train", "val", "test")}
    sensor = load_sensor(Path(__file__).resolve().parents[3] / "config" / "sensor.yaml")  # no draws: only its name
    config = TrainConfig(max_epochs=2, batch_size=8, head_epochs=2, head_batch_size=8, head_cycles=1)
    metrics = train_and_export(sensor, parts, tiny_config, config, tmp_path, progress=False, threads=1,
                               data_source="synthetic")
    phases = json.loads((tmp_path / TRAINING_JSON).read_text())["phases"]
    chosen = phases["fz_threshold"]
    threshold = json.loads((tmp_path / MODEL_JSON).read_text())["fz_threshold_n"]
    # The fusion layer was refitted for the threshold (when that beat the plain fit; the record says which).
    assert set(phases["fusion_refit"]) == {"kept", "iterations", "ridge", "wall_time_s", "threshold_before_n",
                                           "val_rmse_bin_fz_before_n", "val_rmse_bin_fz_after_n"}
    assert (phases["fusion_refit"]["val_rmse_bin_fz_after_n"] < phases["fusion_refit"]["val_rmse_bin_fz_before_n"]) \
        == phases["fusion_refit"]["kept"]
    # A model this briefly trained answers every frame with spurious forces: a threshold beats none.
    assert threshold is not None and threshold > 0 and chosen["fz_threshold_n"] == threshold
    assert min(chosen["val_rmse_bin_fz_n"].values()) < chosen["val_rmse_bin_fz_n"]["none"]
    # The graphs were exported with it: ONNX Runtime equals torch, and no graph outputs a negative Fz.
    assert metrics["backends"]["onnxruntime_fp32"]["max_abs_deviation_from_torch_fp32_n"] < 1e-5
    for precision in ("fp32", "fp16", "int8"):
        predictor = load_predictor(tmp_path, "onnxruntime", precision)
        assert predictor.fz_threshold_n == threshold
        fz = predictor.predict_batch(np.asarray(parts["test"].images), parts["test"].reference)[..., 2]
        assert fz.min() == 0.0, precision
