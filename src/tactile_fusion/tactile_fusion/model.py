"""The force-distribution model: one CNN shared by all cameras, then a linear fusion layer (Trueeb et al. 2020).

Per camera, the difference between the current image and the camera's reference (no-contact) image goes
through the same CNN (3x3 convolutions with batch normalisation and ReLU, 2x max pooling, then fully connected
layers with an activation and dropout) that yields `camera_features` (300) numbers per camera. The features of
all cameras are concatenated in the order of `camera_ids` and a linear fusion layer maps them to rows x cols x 3
bin forces (to the components the training data excites; the others come out as 0, see `estimated_components`). All
cameras of all frames go through the CNN as one batch.

One choice differs from the paper by default, measured (docs/learning.md): the fully connected layers use ReLU
instead of the paper's sigmoid (`feature_activation`).

The network works on normalised forces (the bin forces divided by a global scale per component, see
`force_scale_from_targets`); `forward` multiplies by that scale, so the model (and its ONNX export) returns
newtons. A trained model then soft-thresholds Fz (`fz_threshold_n`, see `to_newtons`).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np
import torch
from torch import nn

from tactile_description import FORCE_COMPONENTS
from tactile_description.value_checks import is_number, is_whole_number

#: Grey levels of a uint8 image: difference images are divided by this so they lie in about [-1, 1].
GREY_LEVELS = 255.0
#: Pixels at this level or above are clipped by the camera: left out of the brightness gain, their difference only a
#: lower bound (difference_images).
SATURATED = 255.0
#: Brightness gains outside this range are clamped (a black or blinded camera gives no usable gain).
GAIN_RANGE = (0.25, 4.0)
#: Activations of the fully connected layers: the paper's sigmoid, or ReLU. With ReLU the model reaches a fifth
#: lower error, and fits its own training frames better too (docs/learning.md).
FEATURE_ACTIVATIONS = {"sigmoid": torch.sigmoid, "relu": torch.relu}


#: The widest layers a ModelConfig takes, far beyond any measured (512 hidden, 300 camera features, 32 channels):
#: a mistyped 1000000000 failed only after the training data was simulated, allocating the model (a traceback).
MAX_FEATURES = 16384
MAX_CONV_CHANNELS = 1024


@dataclass(frozen=True)
class ModelConfig:
    """The network's shape. Camera ids and the bin grid come from the sensor description, not from here."""

    image_size: int = 128                       # square model image (pixels), the sensor's output size
    conv_channels: tuple[int, ...] = (4, 8, 16, 32, 32)  # one conv block (conv, 2x max pool, BN, ReLU) per entry
    hidden_features: int = 512                  # first fully connected layer of the shared CNN
    camera_features: int = 300                  # per-camera features (the paper's 300)
    dropout: float = 0.1
    fusion_rank: int | None = None              # None: one dense matrix; else a rank-limited linear map
    feature_activation: str = "relu"            # of the fully connected layers, a key of FEATURE_ACTIVATIONS

    def __post_init__(self):
        if not is_whole_number(self.image_size):
            raise ValueError(f"ModelConfig: image_size must be a whole number >= 1, got {self.image_size!r}")
        for name in ("hidden_features", "camera_features"):
            if not (is_whole_number(getattr(self, name)) and getattr(self, name) <= MAX_FEATURES):
                raise ValueError(f"ModelConfig: {name} must be a whole number from 1 to {MAX_FEATURES}, got "
                                 f"{getattr(self, name)!r}")
        if not self.conv_channels or not all(is_whole_number(c) and c <= MAX_CONV_CHANNELS for c in self.conv_channels):
            raise ValueError(f"ModelConfig: conv_channels must be one or more whole numbers from 1 to "
                             f"{MAX_CONV_CHANNELS}, got {self.conv_channels!r}")
        pooled = self.image_size // 2 ** len(self.conv_channels)
        if pooled < 1 or self.image_size % 2 ** len(self.conv_channels):
            raise ValueError(f"ModelConfig: image_size {self.image_size} must be divisible by 2^"
                             f"{len(self.conv_channels)} (one 2x pooling per conv block); use fewer conv_channels")
        if not 0.0 <= self.dropout < 1.0:
            raise ValueError(f"ModelConfig: dropout must be in [0, 1), got {self.dropout}")
        if self.fusion_rank is not None and not is_whole_number(self.fusion_rank):
            raise ValueError(f"ModelConfig: fusion_rank must be a whole number >= 1 or None, got {self.fusion_rank!r}")
        if self.feature_activation not in FEATURE_ACTIVATIONS:
            raise ValueError(f"ModelConfig: feature_activation must be one of {list(FEATURE_ACTIVATIONS)}, got "
                             f"{self.feature_activation!r}")

    @property
    def flat_features(self) -> int:
        """Length of the flattened output of the last conv block."""
        side = self.image_size // 2 ** len(self.conv_channels)
        return self.conv_channels[-1] * side * side

    def to_dict(self) -> dict:
        d = asdict(self)
        d["conv_channels"] = list(self.conv_channels)
        return d

    @classmethod
    def from_dict(cls, d: dict) -> ModelConfig:
        """The config of a model.json; models saved before `feature_activation` existed used the sigmoid."""
        d = {"feature_activation": "sigmoid", **d}
        d["conv_channels"] = tuple(d["conv_channels"])
        return cls(**d)


class ConvBlock(nn.Module):
    """3x3 convolution (no bias: batch normalisation follows), 2x max pooling, batch norm, ReLU.

    The paper's order is convolution, batch norm, ReLU, pooling. Max pooling commutes with ReLU and with a
    per-channel affine map of positive scale, so pooling first computes the same function (up to the sign of
    the batch-norm scale, which training is free to choose), but batch norm and ReLU then run on a quarter of the
    pixels: a training step of the conv trunk is 2.3x faster on the CPU (128 vs 57 ms for 64 images at
    128 x 128, one thread, docs/learning.md).
    """

    def __init__(self, in_channels: int, out_channels: int):
        super().__init__()
        self.conv = nn.Conv2d(in_channels, out_channels, kernel_size=3, padding=1, bias=False)
        self.norm = nn.BatchNorm2d(out_channels)
        self.pool = nn.MaxPool2d(2)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        """(N, in, H, W) -> (N, out, H/2, W/2)."""
        return torch.relu(self.norm(self.pool(self.conv(x))))


class FeatureLayer(nn.Module):
    """Fully connected layer, batch normalisation, activation (sigmoid or ReLU), dropout: one layer of the CNN's
    head.

    The batch normalisation before the activation is an addition to the paper's head: it keeps the sigmoid's input
    centred and scaled while Adam moves the weights, so that the units do not saturate (0 or 1 for every
    frame) early in training; with it the head learns several times faster (docs/learning.md). In evaluation
    mode it is a fixed affine map that the ONNX export folds into the layer.
    """

    def __init__(self, in_features: int, out_features: int, dropout: float, activation: str):
        super().__init__()
        self.linear = nn.Linear(in_features, out_features, bias=False)
        self.norm = nn.BatchNorm1d(out_features)
        self.activation = FEATURE_ACTIVATIONS[activation]
        self.dropout = nn.Dropout(dropout)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        """(N, in) -> (N, out), values in (0, 1) (sigmoid) or >= 0 (ReLU)."""
        return self.dropout(self.activation(self.norm(self.linear(x))))


class CameraCNN(nn.Module):
    """The CNN shared by all cameras: difference image -> `camera_features` numbers.

    `last_layer` is the part retrained when a camera is added (modular recalibration); `trunk` and
    `first_layer` stay frozen then.
    """

    def __init__(self, config: ModelConfig):
        super().__init__()
        inputs = (1, *config.conv_channels[:-1])
        self.trunk = nn.Sequential(*(ConvBlock(c_in, c_out) for c_in, c_out in zip(inputs, config.conv_channels,
                                                                                      strict=True)))
        # Channels-last convolutions run about 30 % faster on CPU (oneDNN); the values are the same.
        self.trunk.to(memory_format=torch.channels_last)
        self.first_layer = FeatureLayer(config.flat_features, config.hidden_features, config.dropout,
                                        config.feature_activation)
        self.last_layer = FeatureLayer(config.hidden_features, config.camera_features, config.dropout,
                                       config.feature_activation)

    def set_dropout(self, rate: float) -> float:
        """Set the dropout rate of the fully connected layers (both alike); returns the rate they had."""
        if not 0.0 <= rate < 1.0:
            raise ValueError(f"CameraCNN.set_dropout: rate must be in [0, 1), got {rate}")
        previous = self.first_layer.dropout.p
        self.first_layer.dropout.p = self.last_layer.dropout.p = rate
        return previous

    def hidden(self, difference: torch.Tensor) -> torch.Tensor:
        """(N, 1, H, W) difference images -> (N, hidden_features): everything before `last_layer`."""
        return self.first_layer(self.conv_features(difference))

    def conv_features(self, difference: torch.Tensor) -> torch.Tensor:
        """(N, 1, H, W) difference images -> (N, flat_features): the flattened output of the conv trunk."""
        trunk = self.trunk(difference.contiguous(memory_format=torch.channels_last))
        return torch.flatten(trunk.contiguous(), 1)

    def forward(self, difference: torch.Tensor) -> torch.Tensor:
        """(N, 1, H, W) difference images in [-1, 1] -> (N, camera_features)."""
        return self.last_layer(self.hidden(difference))


class FusionLayer(nn.Module):
    """Linear map from the concatenated camera features to normalised bin forces.

    With `rank` set, the matrix is stored as a product of two thin matrices (still one linear map, of rank
    <= `rank`): for the reference sensor a dense 1200 x 1950 matrix (all three components) is 2.3 M weights (9 MB
    per stored copy), the factored one at rank 512 is 1.6 M; for Fz alone, dense, 0.78 M. The rank costs
    accuracy: the Fz maps of presses anywhere on the surface need about 500 dimensions (projected onto their leading
    384 principal components, the test split's true maps are already 2.9 mN per bin off), and a factored layer also
    slowed the end-to-end training (rank 512: 3.84 mN per bin against 3.67 mN dense; docs/learning.md). The default
    is dense.
    """

    def __init__(self, in_features: int, out_features: int, rank: int | None):
        super().__init__()
        if rank is None or rank >= min(in_features, out_features):
            self.reduce = None
            self.expand = nn.Linear(in_features, out_features)
        else:
            self.reduce = nn.Linear(in_features, rank, bias=False)
            self.expand = nn.Linear(rank, out_features)

    def forward(self, features: torch.Tensor) -> torch.Tensor:
        """(B, in_features) -> (B, out_features)."""
        if self.reduce is not None:
            features = self.reduce(features)
        return self.expand(features)


def difference_images(images: torch.Tensor, reference: torch.Tensor) -> torch.Tensor:
    """Gain-compensated difference of current and reference images, in float32, scaled to about [-1, 1].

    images: (B, C, H, W) uint8 or float grey levels; reference: (C, H, W) or (B, C, H, W), same kind.
    Returns (B, C, H, W) float32: (images / gain - reference) / 255, at saturated pixels no less than 0.

    Computed in float (uint8 differences wrap around: 250 + 10 = 4). `gain` is each image's brightness relative
    to its reference, the least-squares factor over the pixels that are not saturated,
        gain = sum(current * reference) / sum(reference^2),
    clamped to [1/4, 4]; an image without unsaturated pixels gets gain 1. LED flicker, illumination drift
    and exposure changes scale a whole image; without this factor they look like pressure everywhere. A press
    only moves particles, which leaves the factor within about 1e-3 of 1 (docs/learning.md).

    A saturated pixel only says that its level is 255 or more, so its difference is only known to be at least
    255 / gain - reference. Where that bound is positive (a bright particle moved in) it is kept; where it is
    negative the sign is unknown, and the difference is 0 ("nothing moved here"). Taken as it is, the bound made
    the bright particles of an over-exposed image (gain 2.5: 255 / 2.5 = 102 against their 150-255) read as
    particles gone dark: 40.7 mN per bin in the effects scene's over-exposure window (the model shipped on
    2026-11-24); with the bound clipped at 0, 4.6 mN (its clean window: 2.9). In the default scene's frames the
    pixels are saturated almost only where the reference is (1.4e-5 of them), and the test split's error is the same
    to 0.1 uN (docs/learning.md).
    """
    current = images.to(torch.float32)
    reference = reference.to(torch.float32)
    unsaturated = current < SATURATED
    weighted = torch.where(unsaturated, reference, 0.0)
    numerator = torch.sum(current * weighted, dim=(-2, -1), keepdim=True)
    denominator = torch.sum(weighted * weighted, dim=(-2, -1), keepdim=True)
    gain = torch.where(denominator > 0, numerator / torch.clamp(denominator, min=1.0), torch.ones_like(numerator))
    gain = torch.clamp(gain, GAIN_RANGE[0], GAIN_RANGE[1])
    # Both terms are scaled by the same kind of reciprocal, so a uint8 image equal to its reference (gain exactly 1)
    # gives exactly 0.
    difference = current * (1.0 / (gain * GREY_LEVELS)) - reference * (1.0 / GREY_LEVELS)
    return torch.where(unsaturated, difference, torch.clamp(difference, min=0.0))


def camera_batch(difference: torch.Tensor) -> torch.Tensor:
    """(B, C, H, W) difference images -> (B * C, 1, H, W), frame-major: every camera of every frame as one batch of
    the CNN they share."""
    b, c, h, w = difference.shape
    return difference.reshape(b * c, 1, h, w)


class ForceFusionNet(nn.Module):
    """Images of all cameras -> bin forces in newtons.

    camera_ids: the cameras in input order (the fusion layer's feature blocks follow this order).
    force_scale_n: (3,) scale of (fx, fy, fz) used to normalise the targets; stored as a buffer.
    components: the force components the model estimates (see `estimated_components`); the others come out as
        exactly 0. The output always has all three.
    fz_threshold_n: None, or the soft threshold of the Fz output in newtons: each bin's Fz comes out as
        max(Fz - threshold, 0) (see `to_newtons`; fitted by fz_threshold.fit_fz_threshold).
    """

    def __init__(self, config: ModelConfig, camera_ids: tuple[str, ...] | list[str], rows: int, cols: int,
                 force_scale_n: torch.Tensor | None = None, components: tuple[str, ...] = FORCE_COMPONENTS,
                 fz_threshold_n: float | None = None):
        super().__init__()
        if len(camera_ids) < 1 or len(set(camera_ids)) != len(camera_ids):
            raise ValueError(f"ForceFusionNet: camera_ids must be non-empty and unique, got {list(camera_ids)}")
        self.config = config
        self.camera_ids = tuple(camera_ids)
        self.rows, self.cols = int(rows), int(cols)
        self.components = checked_components(components)
        # Output column of each of (fx, fy, fz): its column of the fusion layer, or the zero column appended last.
        self.register_buffer("component_columns", torch.tensor(
            [self.components.index(c) if c in self.components else len(self.components) for c in FORCE_COMPONENTS]),
            persistent=False)
        self.cnn = CameraCNN(config)
        self.fusion = FusionLayer(len(camera_ids) * config.camera_features,
                                  self.rows * self.cols * len(self.components), config.fusion_rank)
        scale = torch.ones(3) if force_scale_n is None else torch.as_tensor(force_scale_n, dtype=torch.float32)
        if scale.shape != (3,) or not bool(torch.all(torch.isfinite(scale) & (scale > 0))):
            raise ValueError(f"ForceFusionNet: force_scale_n must be 3 finite positive numbers, got {scale}")
        self.register_buffer("force_scale_n", scale.clone())
        self.fz_threshold_n = checked_threshold(fz_threshold_n)

    @property
    def n_cameras(self) -> int:
        return len(self.camera_ids)

    @property
    def image_size(self) -> int:
        return self.config.image_size

    @property
    def device(self) -> torch.device:
        """Where its weights are: the CPU, or a GPU while training.fit runs its steps there."""
        return self.force_scale_n.device

    @property
    def component_indices(self) -> list[int]:
        """Indices into (fx, fy, fz) of the estimated components."""
        return [FORCE_COMPONENTS.index(c) for c in self.components]

    def fuse(self, camera_features: torch.Tensor) -> torch.Tensor:
        """(B * C, camera_features) in frame-major order -> (B, rows, cols, 3) normalised forces."""
        batch = camera_features.shape[0] // self.n_cameras
        out = self.fusion(camera_features.reshape(batch, self.n_cameras * self.config.camera_features))
        out = out.reshape(batch, self.rows, self.cols, len(self.components))
        if len(self.components) == len(FORCE_COMPONENTS):
            return out
        return torch.cat([out, torch.zeros_like(out[..., :1])], dim=-1).index_select(-1, self.component_columns)

    def forward_normalised(self, difference: torch.Tensor) -> torch.Tensor:
        """(B, C, H, W) float difference images (see `difference_images`) -> (B, rows, cols, 3) normalised."""
        return self.fuse(self.cnn(camera_batch(difference)))

    def to_newtons(self, normalised: torch.Tensor) -> torch.Tensor:
        """(B, rows, cols, 3) normalised forces of any float type -> float32 newtons, Fz soft-thresholded.

        The threshold: the gel can only be pushed, so a bin's true Fz is never below 0, but the linear fusion
        layer answers every press with small forces of both signs all over the surface. max(Fz - threshold, 0)
        removes them (and lowers the contact's bins by the threshold, which its choice weighs in). With the fusion
        layer refitted for it (fz_threshold.fit_threshold_and_fusion), on the test split of the network shipped on
        2026-11-23: 11 % less error per bin and 3 % less in total force than without a threshold; 14 % less in total
        at the surface's edge (docs/learning.md).
        """
        forces = normalised.float() * self.force_scale_n.float()
        if self.fz_threshold_n is None:
            return forces
        # clamp, not relu: the int8 export finds the fusion layer after the graph's last Relu (export.py).
        return torch.cat([forces[..., :2], torch.clamp(forces[..., 2:] - self.fz_threshold_n, min=0.0)], dim=-1)

    def forward(self, images: torch.Tensor, reference: torch.Tensor) -> torch.Tensor:
        """images (B, C, H, W), reference (C, H, W): uint8 or float grey levels -> (B, rows, cols, 3) newtons."""
        return self.to_newtons(self.forward_normalised(difference_images(images, reference)))


def checked_threshold(fz_threshold_n) -> float | None:
    """None, or the Fz soft threshold as a finite float >= 0 (ValueError otherwise)."""
    if fz_threshold_n is None:
        return None
    # A bool or a string is a mistake in model.json, not a number of newtons (float(True) would be 1 N).
    if not (is_number(fz_threshold_n) and fz_threshold_n >= 0.0):
        raise ValueError(f"fz_threshold_n must be None or a finite number >= 0 (newtons), got {fz_threshold_n!r}")
    return float(fz_threshold_n)


def checked_components(components) -> tuple[str, ...]:
    """A list of force components to estimate, checked (distinct names from FORCE_COMPONENTS, at least one) and put
    in the output's order."""
    names = list(components) if isinstance(components, (list, tuple)) else None
    # strings first: a list such as [["fz"]] is unhashable, and set() raised TypeError (found in review)
    if (not names or not all(isinstance(n, str) for n in names) or len(set(names)) != len(names)
            or set(names) - set(FORCE_COMPONENTS)):
        raise ValueError(f"components must be distinct names from {list(FORCE_COMPONENTS)}, got {components!r}")
    return tuple(c for c in FORCE_COMPONENTS if c in names)


def estimated_components(bin_forces_n: torch.Tensor | np.ndarray) -> tuple[str, ...]:
    """The force components that are not zero in every sample of (N, rows, cols, 3) training forces.

    A component the training data never excites (Fx and Fy of vertical presses) cannot be learnt: its fusion
    weights come out exactly zero, and computing them would be two thirds of the fusion layer's work and of its
    weights in every stored copy of the model (docs/learning.md). Such a component is left out, and the model
    outputs exactly 0 for it, saying so in its model.json. All three if every component is zero (nothing to learn).
    NaN or Inf forces raise ValueError (a NaN is no force that the data excites).
    """
    forces = np.asarray(bin_forces_n).reshape(-1, 3)
    if not np.isfinite(forces).all():
        raise ValueError("estimated_components: the training forces hold NaN or Inf")
    nonzero = np.any(forces != 0, axis=0)
    return tuple(c for c, n in zip(FORCE_COMPONENTS, nonzero, strict=True) if n) or FORCE_COMPONENTS


def force_scale_from_targets(bin_forces_n: torch.Tensor, floor_fraction: float = 0.01) -> torch.Tensor:
    """A safe global scale per force component: the RMS of (fx, fy, fz) over all samples and bins.

    One number per component, not per bin: most bins are zero in most samples, so a per-bin standard
    deviation is zero and dividing by it gives Inf/NaN (SENSOR_BRIEF hazards). A component that is (nearly)
    zero everywhere gets at least `floor_fraction` of the largest component's scale, and an all-zero data
    set gets 1 N, so the scale is always finite and > 0. Targets holding NaN or Inf raise ValueError (their RMS is no
    scale).
    """
    if bin_forces_n.numel() == 0:  # its mean is NaN, which was reported as forces holding NaN (walkthrough)
        raise ValueError("force_scale_from_targets: no training forces (zero frames)")
    rms = torch.sqrt(torch.mean(bin_forces_n.reshape(-1, 3).to(torch.float64) ** 2, dim=0))
    if not torch.isfinite(rms).all():
        raise ValueError("force_scale_from_targets: the training forces hold NaN or Inf (or overflow float64)")
    largest = float(rms.max())
    if not largest > 0.0:
        return torch.ones(3)
    return torch.clamp(rms, min=floor_fraction * largest).to(torch.float32)
