"""The training loop: finite loss, learning, reproducibility, early stopping, checkpoints and resume."""

import copy
import dataclasses
import types

import numpy as np
import pytest
import torch

from tactile_fusion.data import split_indices
from tactile_fusion.model import ForceFusionNet, force_scale_from_targets
from tactile_fusion.sources import ImageSource
from tactile_fusion.training import (
    CheckpointMismatchError,
    TrainConfig,
    build_model,
    epoch_batches,
    fit,
    native_bf16,
    rmse_loss,
    training_device,
)


def sources(frames):
    split = split_indices(len(frames), seed=3)
    train, val = frames.subset(split["train"]), frames.subset(split["val"])
    scale = force_scale_from_targets(torch.from_numpy(train.bin_forces_n))
    return ImageSource(train, scale), ImageSource(val, scale), scale


def trained(frames, config, train_config, **kwargs):
    train, val, scale = sources(frames)
    model = build_model(config, frames.camera_ids, 3, 4, scale, train_config.seed)
    result = fit(model, train, val, train_config, **kwargs)
    return model, result


def same_weights(a, b) -> bool:
    sa, sb = a.state_dict(), b.state_dict()
    return sa.keys() == sb.keys() and all(torch.equal(sa[k], sb[k]) for k in sa)


def test_rmse_gradient_is_finite_and_zero_at_zero_error():
    prediction = torch.zeros(4, 3, requires_grad=True)
    loss = rmse_loss(prediction, torch.zeros(4, 3))
    loss.backward()
    assert torch.isfinite(loss)
    assert torch.equal(prediction.grad, torch.zeros(4, 3))


def test_rmse_matches_the_definition_away_from_zero():
    prediction, target = torch.tensor([1.0, 2.0, 3.0]), torch.tensor([1.0, 0.0, 0.0])
    assert float(rmse_loss(prediction, target, eps=1e-12)) == pytest.approx(np.sqrt(13 / 3), rel=1e-6)


def test_rmse_of_an_empty_batch_is_refused():
    with pytest.raises(ValueError, match="an empty batch has no error"):  # the mean of nothing: NaN
        rmse_loss(torch.zeros(0, 3), torch.zeros(0, 3))


def test_training_lowers_the_validation_error(frames, tiny_config):
    config = TrainConfig(max_epochs=10, batch_size=4, learning_rate=3e-2, patience=10)
    model, result = trained(frames, tiny_config, config)
    assert result.best_val_rmse < 0.9 * result.initial_val_rmse
    assert result.history[-1]["train_rmse"] < 0.95 * result.history[0]["train_rmse"]
    assert len(result.history) == result.epochs_run == 10
    assert all(np.isfinite([h["train_rmse"] for h in result.history]))


def test_same_seed_gives_the_same_weights_and_another_seed_does_not(frames, tiny_config):
    config = TrainConfig(max_epochs=2, batch_size=8, seed=5)
    a, _ = trained(frames, tiny_config, config)
    b, _ = trained(frames, tiny_config, config)
    c, _ = trained(frames, tiny_config, TrainConfig(max_epochs=2, batch_size=8, seed=6))
    assert same_weights(a, b)
    assert not same_weights(a, c)


def test_interrupted_and_resumed_training_equals_an_uninterrupted_run(frames, tiny_config, tmp_path):
    config = TrainConfig(max_epochs=5, batch_size=8, learning_rate=5e-3, seed=2)
    uninterrupted, full = trained(frames, tiny_config, config)

    class Interrupt(Exception):
        pass

    def stop_after_two(epoch, record):
        if epoch == 2:
            raise Interrupt

    checkpoint = tmp_path / "checkpoint.pt"
    with pytest.raises(Interrupt):
        trained(frames, tiny_config, config, checkpoint_path=checkpoint, on_epoch_end=stop_after_two)
    assert checkpoint.exists()
    resumed, result = trained(frames, tiny_config, config, checkpoint_path=checkpoint, resume=True)
    assert same_weights(uninterrupted, resumed)
    assert [h["val_rmse"] for h in result.history] == [h["val_rmse"] for h in full.history]


def test_resuming_with_other_settings_is_refused(frames, tiny_config, tmp_path):
    checkpoint = tmp_path / "checkpoint.pt"
    trained(frames, tiny_config, TrainConfig(max_epochs=1, batch_size=8), checkpoint_path=checkpoint)
    with pytest.raises(ValueError, match="same settings"):
        trained(frames, tiny_config, TrainConfig(max_epochs=1, batch_size=4), checkpoint_path=checkpoint, resume=True)


def checkpoint_as_written_then(frames, tiny_config, config, checkpoint, change):
    """A checkpoint of `config` after one epoch, its saved training settings passed through change(dict) (as an
    older version wrote them)."""
    import torch

    def interrupt(epoch, record):
        raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        trained(frames, tiny_config, config, checkpoint_path=checkpoint, on_epoch_end=interrupt)
    saved = torch.load(checkpoint, weights_only=False)
    change(saved["train_config"])
    torch.save(saved, checkpoint)


def test_a_checkpoint_written_before_a_setting_existed_resumes_with_its_default(frames, tiny_config, tmp_path):
    config = TrainConfig(max_epochs=2, batch_size=8)
    checkpoint = tmp_path / "checkpoint.pt"
    checkpoint_as_written_then(frames, tiny_config, config, checkpoint,
                               lambda saved: saved.pop("recalibration_epochs"))  # before that setting was added
    _, result = trained(frames, tiny_config, config, checkpoint_path=checkpoint, resume=True)
    assert result.epochs_run == 2
    with pytest.raises(ValueError, match="same settings"):
        trained(frames, tiny_config, dataclasses.replace(config, recalibration_epochs=3), checkpoint_path=checkpoint,
                resume=True)


def test_an_end_to_end_checkpoint_from_before_its_dropout_setting_resumes_only_at_the_models_rate(frames, tiny_config,
                                                                                                   tmp_path):
    """Until 2026-11-28 the end-to-end phase trained at the model's dropout (0.1); the default is now none. The model's
    rate, named as on the command line (--end-to-end-dropout 0.1), resumes it; None, which the command line cannot
    give, was the only value accepted at first (review)."""
    then = TrainConfig(max_epochs=3, batch_size=8, end_to_end_dropout=None)
    checkpoint = tmp_path / "checkpoint.pt"
    checkpoint_as_written_then(frames, tiny_config, then, checkpoint, lambda saved: saved.pop("end_to_end_dropout"))
    with pytest.raises(ValueError, match=r"end_to_end_dropout 0.1 \(now 0.0\)"):
        trained(frames, tiny_config, dataclasses.replace(then, end_to_end_dropout=0.0), checkpoint_path=checkpoint,
                resume=True)
    _, named = trained(frames, tiny_config, dataclasses.replace(then, end_to_end_dropout=tiny_config.dropout),
                       checkpoint_path=checkpoint, resume=True)
    checkpoint_as_written_then(frames, tiny_config, then, checkpoint, lambda saved: saved.pop("end_to_end_dropout"))
    _, as_none = trained(frames, tiny_config, then, checkpoint_path=checkpoint, resume=True)
    assert named.epochs_run == as_none.epochs_run == 3


def test_a_checkpoint_from_before_the_head_settings_resumes_only_as_it_was_trained(frames, tiny_config, tmp_path):
    """Head settings whose default changed count as what training did before they existed: no copy, the model's
    dropout. A checkpoint of the time when --head-noise-sigma replaced the frames cannot be resumed at all."""
    old_behaviour = TrainConfig(max_epochs=2, batch_size=8, head_dropout=None, head_noise_sigma=0.0,
                                head_blur_fraction=0.0, head_misalign_fraction=0.0, head_cycles=1,
                                head_precision="fp32")
    checkpoint = tmp_path / "checkpoint.pt"

    def before_the_head_settings(saved):
        for key in ("head_dropout", "head_noise_sigma", "head_blur_fraction", "head_blur_sigma_px",
                    "head_misalign_fraction", "head_misalign_shift_px", "head_misalign_rotation_deg", "head_cycles",
                    "head_precision"):
            del saved[key]

    checkpoint_as_written_then(frames, tiny_config, old_behaviour, checkpoint, before_the_head_settings)
    with pytest.raises(ValueError, match="head_precision 'fp32' \\(now 'bf16'\\)"):  # its steps were float32
        trained(frames, tiny_config, dataclasses.replace(old_behaviour, head_precision="bf16"),
                checkpoint_path=checkpoint, resume=True)
    with pytest.raises(ValueError, match="same settings"):  # today's defaults train another head
        trained(frames, tiny_config, dataclasses.replace(old_behaviour, head_dropout=0.0, head_noise_sigma=1.2,
                                                         head_blur_fraction=0.2, head_misalign_fraction=0.1),
                checkpoint_path=checkpoint, resume=True)
    _, result = trained(frames, tiny_config, old_behaviour, checkpoint_path=checkpoint, resume=True)
    assert result.epochs_run == 2

    def replaced_by_noisy_frames(saved):  # noisy frames instead of the clean ones, as --head-noise-sigma did then
        del saved["head_blur_fraction"]
        saved["head_noise_sigma"] = 1.2

    checkpoint_as_written_then(frames, tiny_config, old_behaviour, checkpoint, replaced_by_noisy_frames)
    with pytest.raises(ValueError, match="replaced the training frames"):
        trained(frames, tiny_config, dataclasses.replace(old_behaviour, head_noise_sigma=1.2),
                checkpoint_path=checkpoint, resume=True)


def test_a_checkpoint_of_a_model_estimating_other_components_is_refused_saying_why(frames, tiny_config, tmp_path):
    """A checkpoint from before models could leave components out estimated all three: resuming it for a model of Fz
    alone (vertical presses) names the cause instead of a size mismatch; the model it was written for resumes."""
    checkpoint = tmp_path / "checkpoint.pt"
    config = TrainConfig(max_epochs=2, batch_size=8)
    checkpoint_as_written_then(frames, tiny_config, config, checkpoint, lambda saved: None)
    saved = torch.load(checkpoint, weights_only=False)
    assert saved.pop("components") == ["fx", "fy", "fz"]
    torch.save(saved, checkpoint)
    train, val, scale = sources(frames)
    fz = build_model(tiny_config, frames.camera_ids, 3, 4, scale, config.seed, ("fz",))
    with pytest.raises(ValueError, match=r"estimating \['fx', 'fy', 'fz'\], but this one estimates \['fz'\]"):
        fit(fz, train, val, config, checkpoint_path=checkpoint, resume=True)
    _, result = trained(frames, tiny_config, config, checkpoint_path=checkpoint, resume=True)
    assert result.epochs_run == 2


@pytest.mark.parametrize(("content", "message"), [
    (b"hello world", r"cannot be read \(UnpicklingError: .*\): it is damaged; delete it"),  # a traceback before
    (None, r"holds a list, not a checkpoint of tactile-fusion train; delete it"),
])
def test_a_damaged_checkpoint_is_refused_saying_what_to_do(frames, tiny_config, tmp_path, content, message):
    checkpoint = tmp_path / "checkpoint.pt"
    if content is None:
        torch.save([1, 2], checkpoint)
    else:
        checkpoint.write_bytes(content)
    train, val, scale = sources(frames)
    model = build_model(tiny_config, frames.camera_ids, 3, 4, scale, 0)
    with pytest.raises(CheckpointMismatchError, match=message):
        fit(model, train, val, TrainConfig(max_epochs=1, batch_size=8), checkpoint_path=checkpoint, resume=True)


def _without_a_weight(saved):
    saved["state"]["best_model"].popitem()


@pytest.mark.parametrize(("edit", "message"), [
    (lambda saved: saved.pop("train_config"), r"train_config is missing, not dict"),
    (lambda saved: saved.update(components=["fq"]), r"its components: components must be distinct names"),
    (lambda saved: saved["state"].update(epoch="1"), r"epoch is str, not int"),
    (lambda saved: saved["state"].update(best_val=True), r"best_val is bool, not float"),
    (_without_a_weight, r"its best weights are of another shape than its weights"),
    (lambda saved: saved["model"].update({name: t.tolist() for name, t in saved["model"].items()}),
     r"its weights are not all tensors"),
    (lambda saved: saved["optimizer"].update(param_groups=[]), r"its optimizer or scheduler state: .*parameter group"),
])
def test_a_hand_edited_checkpoint_is_refused_saying_what_is_wrong(frames, tiny_config, tmp_path, edit, message):
    """Before: a KeyError, ValueError or TypeError traceback, or (a weight gone from the best weights) a RuntimeError
    at the end of the phase."""
    checkpoint = tmp_path / "checkpoint.pt"
    config = TrainConfig(max_epochs=2, batch_size=8)
    checkpoint_as_written_then(frames, tiny_config, config, checkpoint, lambda saved: None)
    saved = torch.load(checkpoint, weights_only=False)
    edit(saved)
    torch.save(saved, checkpoint)
    with pytest.raises(CheckpointMismatchError, match=f"checkpoint {checkpoint} is not as tactile-fusion train writes "
                                                      f"one \\({message}.*\\): it was edited or damaged; delete it"):
        trained(frames, tiny_config, config, checkpoint_path=checkpoint, resume=True)


def test_resuming_a_model_with_another_activation_is_refused(frames, tiny_config, tmp_path):
    """Same weight shapes, another function: load_state_dict alone would accept the checkpoint."""
    checkpoint = tmp_path / "checkpoint.pt"
    sigmoid = dataclasses.replace(tiny_config, feature_activation="sigmoid")
    relu = dataclasses.replace(tiny_config, feature_activation="relu")
    trained(frames, sigmoid, TrainConfig(max_epochs=1, batch_size=8), checkpoint_path=checkpoint)
    with pytest.raises(ValueError, match="same model settings"):
        trained(frames, relu, TrainConfig(max_epochs=1, batch_size=8), checkpoint_path=checkpoint, resume=True)


def test_early_stopping_keeps_the_best_epoch(frames, tiny_config):
    # A learning rate this large makes the validation error jump around: training stops after `patience`
    # epochs without improvement and restores the best weights seen.
    config = TrainConfig(max_epochs=30, batch_size=4, learning_rate=0.5, patience=2)
    model, result = trained(frames, tiny_config, config)
    assert result.stopped_early and result.epochs_run < 30
    assert result.epochs_run - result.best_epoch == 2
    _, val, _ = sources(frames)
    from tactile_fusion.training import normalised_rmse

    assert normalised_rmse(model, val) == pytest.approx(result.best_val_rmse, rel=1e-5)
    # Every epoch ran: not stopped early, even if no epoch beat the start (it was reported as stopped early then).
    _, result = trained(frames, tiny_config, TrainConfig(max_epochs=2, batch_size=4, learning_rate=50.0, patience=2))
    assert result.epochs_run == 2 and result.best_epoch == 0 and not result.stopped_early


def test_keep_last_returns_the_last_epoch_even_after_a_better_one(frames, tiny_config):
    """Phases followed by the least-squares fit keep their last epoch (the fit, not the epoch, is judged)."""
    config = TrainConfig(max_epochs=6, batch_size=4, learning_rate=0.5, patience=6)
    model, result = trained(frames, tiny_config, config, keep="last")
    assert result.best_epoch < result.epochs_run == 6  # the jumpy validation error peaked before the end
    assert result.kept_epoch == 6
    _, val, _ = sources(frames)
    from tactile_fusion.training import normalised_rmse

    assert normalised_rmse(model, val) == pytest.approx(result.history[-1]["val_rmse"], rel=1e-5)
    assert normalised_rmse(model, val) > result.best_val_rmse
    best_model, best = trained(frames, tiny_config, config)
    assert best.kept_epoch == best.best_epoch
    assert normalised_rmse(best_model, val) == pytest.approx(best.best_val_rmse, rel=1e-5)
    with pytest.raises(ValueError, match="keep must be 'best' or 'last', got 'first'"):
        trained(frames, tiny_config, config, keep="first")


def test_batch_of_one_zero_bins_and_zero_error_stay_finite(frames, tiny_config):
    """Batch size 1 (BatchNorm over one frame), and targets that are zero in every bin and sample."""
    zero = frames.subset(np.arange(len(frames)))
    zero.bin_forces_n[...] = 0.0
    model, result = trained(zero, tiny_config, TrainConfig(max_epochs=1, batch_size=1))
    assert np.isfinite(result.best_val_rmse)
    assert all(torch.isfinite(p).all() for p in model.parameters())
    # A batch the model already predicts exactly: the loss gradient is zero, not NaN.
    model.train()
    train, _, scale = sources(zero)
    prediction = train.predict(model, np.arange(3))
    loss = rmse_loss(prediction, prediction.detach())
    loss.backward()
    assert all(torch.isfinite(p.grad).all() for p in model.parameters() if p.grad is not None)


def test_epoch_batches_cover_every_frame_once_and_depend_on_seed_and_epoch():
    batches = epoch_batches(10, 3, seed=1, epoch=1)
    assert sorted(np.concatenate(batches)) == list(range(10))
    assert [len(b) for b in batches] == [3, 3, 3, 1]
    assert np.array_equal(np.concatenate(batches), np.concatenate(epoch_batches(10, 3, seed=1, epoch=1)))
    assert not np.array_equal(np.concatenate(batches), np.concatenate(epoch_batches(10, 3, seed=1, epoch=2)))


def test_a_last_batch_too_small_for_batch_norm_joins_the_previous_one():
    batches = epoch_batches(10, 3, seed=1, epoch=1, min_batch=2)
    assert [len(b) for b in batches] == [3, 3, 4]
    assert sorted(np.concatenate(batches)) == list(range(10))


def test_single_camera_training_with_one_frame_batches_is_refused_clearly(frames, tiny_config):
    one_camera = frames.select_cameras(("left",))
    train, val, scale = sources(one_camera)
    model = build_model(tiny_config, ("left",), 3, 4, scale, seed=0)
    with pytest.raises(ValueError, match="batch_size must be >= 2 for a 1-camera model"):
        fit(model, train, val, TrainConfig(max_epochs=1, batch_size=1))
    with pytest.raises(ValueError, match="needs at least 2 training frames"):
        fit(model, ImageSource(one_camera.subset([0]), scale), val, TrainConfig(max_epochs=1, batch_size=2))
    result = fit(model, train, val, TrainConfig(max_epochs=1, batch_size=2))  # 33 frames: the last one joins
    assert np.isfinite(result.best_val_rmse)


@pytest.mark.parametrize("setting, value, message", [
    ("batch_size", 0, "batch_size must be a whole number >= 1"),
    ("learning_rate", float("inf"), "learning_rate must be a finite number > 0, got inf"),
    ("learning_rate", float("nan"), "learning_rate must be a finite number > 0, got nan"),
    ("head_learning_rate", float("inf"), "head_learning_rate must be a finite number > 0, got inf"),
    ("head_learning_rate", 0.0, "head_learning_rate must be a finite number > 0, got 0.0"),
    ("loss_eps", float("inf"), "loss_eps must be a finite number > 0"),
    ("min_learning_rate", -1e-5, "min_learning_rate must be a finite number >= 0, got -1e-05"),
    ("min_learning_rate", float("nan"), "min_learning_rate must be a finite number >= 0, got nan"),
    ("seed", -1, "seed must be a whole number from 0 to 4294967295, got -1"),
    ("seed", 2**32, "seed must be a whole number from 0 to 4294967295, got 4294967296"),
    ("seed", 1.5, "seed must be a whole number"),
])
def test_bad_train_config_is_rejected(setting, value, message):
    with pytest.raises(ValueError, match=f"TrainConfig.{message}"):
        TrainConfig(**{setting: value})


@pytest.mark.parametrize("device", ["gpu", "CUDA", "cpu:1", "cuda:x", "cuda:-1", "meta", "", 0])
def test_a_device_other_than_the_cpu_or_a_cuda_gpu_is_rejected(device):
    with pytest.raises(ValueError, match=f"TrainConfig.device must be 'cpu', 'cuda' or 'cuda:N', got {device!r}"):
        TrainConfig(device=device)


def test_training_on_a_gpu_this_machine_lacks_is_refused_before_a_step_and_leaves_the_model(frames, tiny_config):
    missing = f"cuda:{torch.cuda.device_count()}"  # one past the last GPU: cuda:0 on a machine without one
    says_what_it_has = rf"TrainConfig.device '{missing}': this (torch \(.*\) sees no CUDA GPU|machine has \d+ CUDA)"
    with pytest.raises(ValueError, match=says_what_it_has):
        training_device(missing)
    model, _ = trained(frames, tiny_config, TrainConfig(max_epochs=1, batch_size=8, seed=2))
    before = copy.deepcopy(model.state_dict())
    train, val, _ = sources(frames)
    with pytest.raises(ValueError, match=says_what_it_has):
        fit(model, train, val, TrainConfig(max_epochs=1, batch_size=8, seed=2, device=missing))
    assert all(torch.equal(value, model.state_dict()[key]) for key, value in before.items())
    assert training_device("cpu") == torch.device("cpu")


def test_fit_returns_the_model_to_the_cpu_also_when_training_stops(frames, tiny_config, monkeypatch):
    """The callers of fit (caches, least-squares fits, export) compute on the CPU: a phase on a GPU that stops must not
    leave the model there. Spied on the CPU, where both moves are to the CPU."""
    moves = []
    move = ForceFusionNet.to
    monkeypatch.setattr(ForceFusionNet, "to", lambda model, device: moves.append(str(device)) or move(model, device))

    def stop(epoch, record):
        raise InterruptedError("stopped after the first epoch")

    with pytest.raises(InterruptedError):
        trained(frames, tiny_config, TrainConfig(max_epochs=2, batch_size=8, seed=2), on_epoch_end=stop)
    assert moves == ["cpu", "cpu"]  # to config.device for the steps, back to the CPU after the stop


@pytest.mark.parametrize("compute_capability, precision", [(7, "fp32"), (8, "bf16"), (9, "bf16")])
def test_head_precision_auto_on_a_gpu_is_bf16_from_ampere_on(monkeypatch, compute_capability, precision):
    """Older GPUs emulate bf16, slower than float32 (torch.cuda.is_bf16_supported counts that emulation; review). The
    GPU's properties are stood in for here: CI has no GPU."""
    monkeypatch.setattr(torch.cuda, "get_device_properties",
                        lambda device: types.SimpleNamespace(major=compute_capability))
    assert native_bf16(torch.device("cuda:0")) is (precision == "bf16")
    assert TrainConfig(device="cuda").head_phase().head_precision == precision
    assert TrainConfig(device="cuda", head_precision="fp32").head_phase().head_precision == "fp32"


def test_batch_sizes_are_checked_against_the_camera_count_before_training():
    config = TrainConfig(batch_size=1, head_batch_size=2)
    config.check_batch_sizes(2)  # two cameras: one frame brings the two images batch normalisation needs
    with pytest.raises(ValueError, match="batch_size must be >= 2 for a 1-camera model"):
        config.check_batch_sizes(1)
    with pytest.raises(ValueError, match="head_batch_size must be >= 2 for a 1-camera model"):
        TrainConfig(head_batch_size=1).check_batch_sizes(1)


def test_head_phase_has_its_own_epochs_learning_rate_and_batch_size():
    config = TrainConfig(max_epochs=7, batch_size=16, learning_rate=1e-3, head_epochs=30, head_learning_rate=4e-3,
                         head_batch_size=64)
    head = config.head_phase()
    assert (head.max_epochs, head.learning_rate, head.batch_size, head.head_epochs) == (30, 4e-3, 64, 0)
    assert head.seed == config.seed and head.patience == 30  # no early stopping during the warm restart
    with pytest.raises(ValueError, match="head_batch_size"):
        TrainConfig(head_batch_size=0)


def test_recalibration_phase_is_a_head_phase_of_its_own_length():
    config = TrainConfig(max_epochs=7, patience=3, head_epochs=30, head_learning_rate=4e-3, head_batch_size=64,
                         recalibration_epochs=11)
    recalibration = config.recalibration_phase()
    assert (recalibration.max_epochs, recalibration.learning_rate, recalibration.batch_size) == (11, 4e-3, 64)
    assert recalibration.patience == 11 and recalibration.head_epochs == 0
    assert TrainConfig(head_epochs=0, recalibration_epochs=5).recalibration_phase().max_epochs == 5
    with pytest.raises(ValueError, match="recalibration_epochs"):
        TrainConfig(recalibration_epochs=0)


def test_head_precision_resolves_auto_by_the_cpu_and_rejects_unknown_ones(frames, tiny_config):
    assert TrainConfig().head_phase().head_precision == ("bf16" if native_bf16() else "fp32")
    assert TrainConfig(head_precision="fp32").recalibration_phase().head_precision == "fp32"
    assert TrainConfig(head_precision="bf16").head_phase().head_precision == "bf16"
    with pytest.raises(ValueError, match="head_precision must be one of"):
        TrainConfig(head_precision="fp16")
    with pytest.raises(ValueError, match="step_precision must be 'bf16' or 'fp32', got 'auto'"):  # unresolved
        trained(frames, tiny_config, TrainConfig(max_epochs=1, batch_size=8), step_precision="auto")
    # native_bf16 asks torch.cpu's private queries; a torch that renamed them would silently train in float32
    assert callable(torch.cpu._is_avx512_bf16_supported) and callable(torch.cpu._is_amx_tile_supported)
