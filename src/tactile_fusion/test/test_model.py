"""The network: shapes from the sensor description, shared CNN over all cameras, safe scaling, hard inputs."""

import dataclasses
from pathlib import Path

import numpy as np
import pytest
import torch

from tactile_description import load_sensor
from tactile_fusion.model import (
    ConvBlock,
    ForceFusionNet,
    FusionLayer,
    ModelConfig,
    difference_images,
    estimated_components,
    force_scale_from_targets,
)
from tactile_fusion.training import rmse_loss

CONFIG = Path(__file__).resolve().parents[3] / "config"


@pytest.mark.parametrize("sensor_file", ["sensor.yaml", "skin_3x3.yaml"])
def test_shapes_follow_the_sensor_description(sensor_file):
    sensor = load_sensor(CONFIG / sensor_file)
    size = sensor.cameras[0].output_size[0]
    model = ForceFusionNet(ModelConfig(image_size=size), sensor.camera_ids, sensor.grid.rows, sensor.grid.cols).eval()
    images = torch.randint(0, 256, (2, sensor.n_cameras, size, size), dtype=torch.uint8)
    reference = torch.randint(0, 256, (sensor.n_cameras, size, size), dtype=torch.uint8)
    with torch.no_grad():
        out = model(images, reference)
    assert out.shape == (2, sensor.grid.rows, sensor.grid.cols, 3)
    assert out.dtype == torch.float32
    assert model.fusion.expand.out_features == sensor.grid.n_bins * 3
    first = model.fusion.reduce if model.fusion.reduce is not None else model.fusion.expand
    in_features = first.in_features
    assert in_features == 300 * sensor.n_cameras


def test_all_cameras_of_all_frames_go_through_the_cnn_as_one_batch(tiny_config):
    model = ForceFusionNet(tiny_config, ("a", "b", "c"), 3, 4).eval()
    calls = []
    model.cnn.register_forward_hook(lambda module, inputs, output: calls.append(inputs[0].shape))
    with torch.no_grad():
        model(torch.zeros(5, 3, 16, 16, dtype=torch.uint8), torch.zeros(3, 16, 16, dtype=torch.uint8))
    assert calls == [(15, 1, 16, 16)]


def test_cnn_is_shared_so_swapping_cameras_swaps_feature_blocks(tiny_config):
    model = ForceFusionNet(tiny_config, ("a", "b"), 3, 4).eval()
    rng = np.random.default_rng(1)
    images = torch.from_numpy(rng.integers(0, 256, (1, 2, 16, 16), dtype=np.uint8))
    reference = torch.from_numpy(rng.integers(0, 256, (2, 16, 16), dtype=np.uint8))
    with torch.no_grad():
        features = model.cnn(difference_images(images, reference).reshape(2, 1, 16, 16))
        swapped = model.cnn(difference_images(images[:, [1, 0]], reference[[1, 0]]).reshape(2, 1, 16, 16))
    torch.testing.assert_close(features, swapped[[1, 0]])


def test_difference_is_computed_in_float_without_uint8_wrap_around():
    reference = torch.full((1, 8, 8), 100, dtype=torch.uint8)
    reference[0, 0, :2] = torch.tensor([10, 250], dtype=torch.uint8)
    images = reference.clone()[None]
    images[0, 0, 0, :2] = torch.tensor([250, 4], dtype=torch.uint8)   # uint8 arithmetic: 240 and 10 (wrapped)
    current, ref = images.double(), reference.double()
    gain = (current * ref).sum() / (ref * ref).sum()
    expected = (current / gain - ref) / 255.0
    diff = difference_images(images, reference)
    torch.testing.assert_close(diff.double(), expected, rtol=0, atol=1e-6)
    assert diff[0, 0, 0, 0] > 0.9 and diff[0, 0, 0, 1] < -0.9


def test_brightness_change_of_the_whole_image_is_compensated():
    rng = np.random.default_rng(0)
    reference = torch.from_numpy(rng.integers(20, 200, (2, 32, 32), dtype=np.uint8))
    unchanged = difference_images(reference[None], reference)
    assert torch.equal(unchanged, torch.zeros_like(unchanged))
    brighter = torch.clamp(torch.round(reference.double() * 1.2), max=255).to(torch.uint8)[None]
    assert difference_images(brighter, reference).abs().max() < 1.0 / 255.0  # only the rounding is left
    raw = (brighter.double() - reference.double()) / 255.0
    assert raw.abs().max() > 30.0 / 255.0  # what a plain difference would call a press everywhere


def test_saturated_pixels_are_left_out_of_the_gain_and_give_a_difference_no_less_than_0():
    reference = torch.full((1, 16, 16), 60, dtype=torch.uint8)
    reference[0, :4] = 200
    over_exposed = torch.clamp(reference.double() * 2.0, max=255).to(torch.uint8)[None]   # 200 -> 255 (clipped)
    over_exposed[0, 0, 15, 15] = 255            # a bright particle moved onto a dark pixel: 255 / 2 - 60 > 0
    diff = difference_images(over_exposed, reference)
    torch.testing.assert_close(diff[0, 0, 4:15], torch.zeros(11, 16), rtol=0, atol=1e-6)  # gain found: exactly 2
    # 255 / 2 against 200 would read as particles gone dark: the sign is unknown, the difference 0
    assert torch.equal(diff[0, 0, :4], torch.zeros(4, 16))
    torch.testing.assert_close(diff[0, 0, 15, 15].double(), torch.tensor((127.5 - 60.0) / 255.0, dtype=torch.float64),
                               rtol=0, atol=1e-6)


def test_blind_frames_give_finite_differences():
    reference = torch.full((1, 16, 16), 60, dtype=torch.uint8)
    reference[0, :4] = 200
    for level in (0, 255):
        frame = torch.full((1, 1, 16, 16), level, dtype=torch.uint8)
        assert torch.isfinite(difference_images(frame, reference)).all()


def test_force_scale_is_finite_and_positive_when_most_bins_are_zero():
    forces = torch.zeros(10, 3, 4, 3)
    forces[0, 1, 2, 2] = 0.3          # one loaded bin in one sample; fx, fy zero everywhere
    scale = force_scale_from_targets(forces)
    assert torch.isfinite(scale).all() and (scale > 0).all()
    assert scale[2] == pytest.approx(0.3 / np.sqrt(10 * 12), rel=1e-5)
    assert scale[0] == pytest.approx(0.01 * float(scale[2]), rel=1e-5)  # floored, not zero
    normalised = forces / scale
    assert torch.isfinite(normalised).all()


def test_force_scale_of_all_zero_data_is_one_and_of_no_data_refused():
    torch.testing.assert_close(force_scale_from_targets(torch.zeros(4, 2, 2, 3)), torch.ones(3))
    with pytest.raises(ValueError, match=r"no training forces \(zero frames\)"):  # said "hold NaN or Inf"
        force_scale_from_targets(torch.zeros(0, 2, 2, 3))


@pytest.mark.parametrize("bad", [float("nan"), float("inf")])
def test_non_finite_forces_have_no_scale_and_no_components(bad):
    """A NaN in the training forces used to give the scale 1 N silently and count as a force the data excites."""
    forces = torch.zeros(4, 2, 2, 3)
    forces[1, 0, 1, 2], forces[2, 1, 1, 0] = 0.3, bad
    with pytest.raises(ValueError, match="NaN or Inf"):
        force_scale_from_targets(forces)
    with pytest.raises(ValueError, match="NaN or Inf"):
        estimated_components(forces)


def test_forward_returns_newtons_through_the_force_scale(tiny_config):
    scale = torch.tensor([0.001, 0.002, 0.05])
    model = ForceFusionNet(tiny_config, ("a",), 2, 2, scale).eval()
    images = torch.randint(0, 256, (3, 1, 16, 16), dtype=torch.uint8)
    reference = torch.randint(0, 256, (1, 16, 16), dtype=torch.uint8)
    with torch.no_grad():
        normalised = model.forward_normalised(difference_images(images, reference))
        torch.testing.assert_close(model(images, reference), normalised * scale)


def test_the_fz_threshold_zeroes_fz_below_it_shifts_fz_above_it_and_leaves_fx_fy_alone(tiny_config):
    scale = torch.tensor([0.001, 0.002, 0.05])
    plain = ForceFusionNet(tiny_config, ("a",), 1, 4, scale)
    thresholded = ForceFusionNet(tiny_config, ("a",), 1, 4, scale, fz_threshold_n=0.01)
    # normalised Fz 0.1, 0.2, 0.4 and -0.2 (5, 10, 20 and -10 mN); Fx and Fy of both signs
    normalised = torch.tensor([[[[1.0, -1.0, 0.1], [-2.0, 2.0, 0.2], [3.0, 0.5, 0.4], [-1.0, 1.0, -0.2]]]])
    newtons = normalised * scale
    torch.testing.assert_close(plain.to_newtons(normalised), newtons)
    out = thresholded.to_newtons(normalised)
    torch.testing.assert_close(out[..., :2], newtons[..., :2])
    torch.testing.assert_close(out[..., 2], torch.tensor([[[0.0, 0.0, 0.01, 0.0]]]))
    assert out.dtype == torch.float32 and thresholded.to_newtons(normalised.half()).dtype == torch.float32


@pytest.mark.parametrize("threshold", [-0.001, float("nan"), float("inf"), "high", "0.002", True])
def test_a_bad_fz_threshold_is_rejected(tiny_config, threshold):
    with pytest.raises(ValueError, match="fz_threshold_n must be None or a finite number >= 0"):
        ForceFusionNet(tiny_config, ("a",), 1, 4, fz_threshold_n=threshold)


@pytest.mark.parametrize("level", [0, 255])
def test_all_black_and_saturated_frames_give_finite_forces(tiny_config, level):
    model = ForceFusionNet(tiny_config, ("a", "b"), 3, 4).eval()
    reference = torch.randint(0, 256, (2, 16, 16), dtype=torch.uint8)
    with torch.no_grad():
        out = model(torch.full((1, 2, 16, 16), level, dtype=torch.uint8), reference)
    assert torch.isfinite(out).all()


def test_constant_input_and_batch_of_one_in_training_mode_stay_finite(tiny_config):
    """BatchNorm in training mode sees zero variance (constant difference image, one frame): eps keeps it finite."""
    model = ForceFusionNet(tiny_config, ("a", "b"), 3, 4).train()
    frame = torch.full((1, 2, 16, 16), 77, dtype=torch.uint8)
    reference = torch.full((2, 16, 16), 77, dtype=torch.uint8)
    out = model(frame, reference)
    loss = rmse_loss(out, torch.zeros_like(out))
    loss.backward()
    assert torch.isfinite(out).all() and torch.isfinite(loss)
    assert all(torch.isfinite(p.grad).all() for p in model.parameters() if p.grad is not None)


def test_pooling_before_batch_norm_is_the_papers_conv_block_when_the_norm_scale_is_positive():
    """The block pools first for speed; with a positive batch-norm scale that is conv, BN, ReLU, pool exactly."""
    torch.manual_seed(0)
    block = ConvBlock(2, 5).eval()
    with torch.no_grad():
        block.norm.weight.copy_(torch.rand(5) + 0.1)
        block.norm.bias.copy_(torch.randn(5))
        block.norm.running_mean.copy_(torch.randn(5))
        block.norm.running_var.copy_(torch.rand(5) + 0.5)
        x = torch.randn(3, 2, 16, 16)
        papers_order = block.pool(torch.relu(block.norm(block.conv(x))))
        torch.testing.assert_close(block(x), papers_order)
        block.norm.weight.mul_(-1.0)                      # a negative scale turns max pooling into min pooling
        assert not torch.allclose(block(x), block.pool(torch.relu(block.norm(block.conv(x)))))


def test_factored_fusion_is_one_linear_map_of_limited_rank():
    layer = FusionLayer(12, 30, rank=3)
    x = torch.randn(5, 12)
    y = torch.randn(5, 12)
    with torch.no_grad():
        torch.testing.assert_close(layer(x + 2 * y) - layer(torch.zeros(1, 12)),
                                   (layer(x) - layer(torch.zeros(1, 12))) + 2 * (layer(y) - layer(torch.zeros(1, 12))))
        matrix = layer(torch.eye(12)) - layer(torch.zeros(1, 12))
    assert torch.linalg.matrix_rank(matrix) == 3
    assert FusionLayer(12, 30, rank=None).reduce is None


@pytest.mark.parametrize("kwargs, message", [
    (dict(image_size=100, conv_channels=(4, 4, 4)), "divisible"),
    (dict(dropout=1.0), "dropout"),
    (dict(fusion_rank=0), "fusion_rank"),
    (dict(fusion_rank=-3), "fusion_rank"),
    (dict(conv_channels=(4, 0, 8)), "conv_channels must be one or more whole numbers from 1 to 1024"),
    (dict(conv_channels=(4, -8)), "conv_channels must be one or more whole numbers from 1 to 1024"),
    (dict(conv_channels=()), "conv_channels must be one or more whole numbers from 1 to 1024"),
    (dict(conv_channels=(4, 1025)), r"conv_channels must be one or more whole numbers from 1 to 1024, got \(4, 1025\)"),
    (dict(hidden_features=0), "hidden_features must be a whole number from 1 to 16384"),
    (dict(hidden_features=10**9), "hidden_features must be a whole number from 1 to 16384, got 1000000000"),
    (dict(camera_features=-300), "camera_features must be a whole number from 1 to 16384"),
    (dict(camera_features=True), "camera_features must be a whole number from 1 to 16384"),
    (dict(image_size=0), "image_size must be a whole number >= 1"),
    (dict(feature_activation="tanh"), "feature_activation must be one of"),
])
def test_bad_model_config_is_rejected_with_a_clear_error(kwargs, message):
    with pytest.raises(ValueError, match=message):
        ModelConfig(**kwargs)


def test_bad_camera_ids_and_force_scale_are_rejected(tiny_config):
    with pytest.raises(ValueError, match="unique"):
        ForceFusionNet(tiny_config, ("a", "a"), 3, 4)
    with pytest.raises(ValueError, match="force_scale_n"):
        ForceFusionNet(tiny_config, ("a",), 3, 4, torch.tensor([1.0, 0.0, 1.0]))


def test_a_model_of_fz_alone_computes_a_third_of_the_fusion_and_outputs_exact_zeros_for_fx_and_fy(tiny_config,
                                                                                                  fz_only_copy):
    torch.manual_seed(0)
    model = ForceFusionNet(tiny_config, ("a", "b"), 3, 4).eval()
    fz = fz_only_copy(model)
    assert fz.components == ("fz",) and fz.component_indices == [2]
    assert fz.fusion.expand.out_features == 3 * 4 == model.fusion.expand.out_features // 3
    images = torch.randint(0, 256, (5, 2, 16, 16), dtype=torch.uint8)
    reference = torch.randint(0, 256, (2, 16, 16), dtype=torch.uint8)
    with torch.no_grad():
        full, alone = model(images, reference), fz(images, reference)
    assert alone.shape == full.shape == (5, 3, 4, 3)
    assert torch.equal(alone[..., 2], full[..., 2]) and bool(full[..., 2].abs().max() > 0)
    assert torch.equal(alone[..., :2], torch.zeros(5, 3, 4, 2))


def test_a_model_can_leave_out_any_components_and_keeps_the_output_order(tiny_config):
    model = ForceFusionNet(tiny_config, ("a",), 2, 2, components=("fz", "fx")).eval()
    assert model.components == ("fx", "fz")  # the output's order, whatever order they were named in
    with torch.no_grad():
        model.fusion.expand.bias.copy_(torch.tensor([1.0, 2.0] * 4))  # (fx, fz) of each bin
        out = model.fuse(torch.zeros(1, tiny_config.camera_features))
    torch.testing.assert_close(out, torch.tensor([1.0, 0.0, 2.0]).expand(1, 2, 2, 3))


@pytest.mark.parametrize("components", [(), ("fz", "fz"), ("fz", "tz")])
def test_bad_components_are_rejected(tiny_config, components):
    with pytest.raises(ValueError, match="components must be distinct names from"):
        ForceFusionNet(tiny_config, ("a",), 3, 4, components=components)


def test_the_components_estimated_are_those_the_training_forces_excite():
    forces = np.zeros((6, 3, 4, 3), dtype=np.float32)
    assert estimated_components(forces) == ("fx", "fy", "fz")  # nothing to learn: all three, as before
    forces[2, 1, 1, 2] = 0.4
    assert estimated_components(forces) == ("fz",)             # vertical presses
    forces[5, 0, 3, 0] = -1e-6
    assert estimated_components(torch.from_numpy(forces)) == ("fx", "fz")


def test_config_round_trips_through_a_dict():
    config = ModelConfig(conv_channels=(2, 4, 8), fusion_rank=None)
    assert ModelConfig.from_dict(config.to_dict()) == config


def test_a_model_json_from_before_the_activation_choice_loads_with_the_sigmoid():
    old = ModelConfig(feature_activation="relu").to_dict()
    del old["feature_activation"]
    assert ModelConfig.from_dict(old).feature_activation == "sigmoid"


def test_camera_features_are_those_of_the_chosen_activation(tiny_config):
    torch.manual_seed(0)
    images = torch.randn(6, 1, tiny_config.image_size, tiny_config.image_size)
    features = {}
    for activation in ("sigmoid", "relu"):
        model = ForceFusionNet(dataclasses.replace(tiny_config, feature_activation=activation), ("a", "b"), 3, 4)
        with torch.no_grad():
            features[activation] = model.eval().cnn(images)
    assert features["sigmoid"].shape == features["relu"].shape == (6, tiny_config.camera_features)
    assert float(features["sigmoid"].min()) > 0 and float(features["sigmoid"].max()) < 1
    assert float(features["relu"].min()) == 0 < float(features["relu"].max())  # ReLU zeroes the negative ones
