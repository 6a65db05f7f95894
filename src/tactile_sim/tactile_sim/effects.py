"""Imperfections of a real sensor that a scene can name: noise, blur, light changes, saturation, dropouts, drift.

A scene lists effects by name (see docs/simulator.md); `parse_effect` checks the YAML and `bind_effects` turns
the specs into per-stream objects for one sensor. Only the named effects exist at run time: the simulator loops
over the bound list, so an effect that is not named does no work at all.

Effects run stage by stage in the physical order of the imaging chain, whatever their order in the scene file;
effects of the same stage run in the file's order:
  OPTICS    the light reaching the lens: camera misalignment, reference drift (gel ageing), defocus blur
  LIGHT     the light level: illumination drift, LED flicker, exposure (gain, saturation)
  SENSOR    the image sensor: noise
  (the camera then clips to 0..255 and quantises to uint8: saturation happens here)
  TRANSPORT the link to the computer: a dropped or frozen camera
Image-space effects act on the model images (float32 (C, H, W) grey levels, before quantisation).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field, fields
from typing import ClassVar

import cv2
import numpy as np

from tactile_description.value_checks import is_number, is_whole_number

OPTICS, LIGHT, SENSOR, TRANSPORT = 0, 1, 2, 3

#: Length of the pre-generated Gaussian noise pool, in samples (4 MiB of float32). Each frame reads one
#: contiguous window at a random offset, so noise costs one addition per pixel instead of a Gaussian draw.
NOISE_POOL_SAMPLES = 1 << 20


class SceneError(ValueError):
    """A scene file (or scene mapping) with a missing key, an unknown name or an impossible value."""


@dataclass(frozen=True)
class EffectContext:
    """What binding an effect needs to know about the stream it will run in."""

    camera_ids: tuple[str, ...]
    image_shape: tuple[int, int]   # (H, W) of the model images
    frame_rate_hz: float
    seed: int
    where: str = "scene"


@dataclass(frozen=True)
class EffectSpec:
    """Common keys of every effect: which cameras (default all) and which frames [first, stop) (default all)."""

    name: ClassVar[str] = ""
    stage: ClassVar[int] = OPTICS
    cameras: tuple[str, ...] | None = None
    frames: tuple[int, int] | None = None

    def camera_mask(self, ctx: EffectContext) -> np.ndarray:
        if self.cameras is None:
            return np.ones(len(ctx.camera_ids), dtype=bool)
        unknown = [c for c in self.cameras if c not in ctx.camera_ids]
        if unknown:
            raise SceneError(f"{ctx.where}: effect {self.name!r} names cameras {unknown}, but the sensor's cameras "
                             f"are {list(ctx.camera_ids)}")
        return np.array([c in self.cameras for c in ctx.camera_ids])

    def active(self, frame_index: int) -> bool:
        return self.frames is None or self.frames[0] <= frame_index < self.frames[1]

    def bind(self, ctx: EffectContext, rng: np.random.Generator) -> BoundEffect:
        raise NotImplementedError


class BoundEffect:
    """An effect ready to run on one stream: `apply` changes the float32 (C, H, W) images in place."""

    def __init__(self, spec: EffectSpec, ctx: EffectContext):
        self.spec = spec
        self.stage = spec.stage
        self.mask = spec.camera_mask(ctx)
        self.selected = np.flatnonzero(self.mask)
        self.all_cameras = bool(self.mask.all())

    def apply(self, images: np.ndarray, frame_index: int, time_s: float) -> None:
        raise NotImplementedError


# --- OPTICS ---------------------------------------------------------------------------------------------------------

def _warp_matrix(shape: tuple[int, int], shift_px: Sequence[float], rotation_deg: float) -> np.ndarray:
    """2x3 affine matrix: rotation about the image centre (the principal point), then a shift."""
    height, width = shape
    matrix = cv2.getRotationMatrix2D(((width - 1) / 2.0, (height - 1) / 2.0), rotation_deg, 1.0)
    matrix[:, 2] += np.asarray(shift_px, dtype=np.float64)
    return matrix


def _warp(image: np.ndarray, matrix: np.ndarray) -> np.ndarray:
    return cv2.warpAffine(image, matrix, (image.shape[1], image.shape[0]), flags=cv2.INTER_LINEAR,
                          borderMode=cv2.BORDER_REPLICATE)


def misalign(image: np.ndarray, shift_px: Sequence[float], rotation_deg: float) -> np.ndarray:
    """One camera image (H, W), float32 or uint8, seen by a camera knocked off its pose (see CameraMisalignment):
    turned by `rotation_deg` about the image centre, then shifted by `shift_px` (x, y) pixels, bilinear, edges
    replicated. The same dtype comes back."""
    return _warp(image, _warp_matrix(image.shape, shift_px, rotation_deg))


@dataclass(frozen=True)
class CameraMisalignment(EffectSpec):
    """A camera knocked off its calibrated pose after the reference frame was taken.

    Modelled in the image: a rotation about the optical axis (exact for a fisheye, whose image then turns about
    the principal point) and a shift (a small tilt, to first order). Default: all cameras.
    """

    name: ClassVar[str] = "camera_misalignment"
    stage: ClassVar[int] = OPTICS
    shift_px: tuple[float, float] = (0.0, 0.0)
    rotation_deg: float = 0.0

    def bind(self, ctx, rng):
        return _Misalignment(self, ctx)


class _Misalignment(BoundEffect):
    def __init__(self, spec: CameraMisalignment, ctx: EffectContext):
        super().__init__(spec, ctx)
        self.matrix = _warp_matrix(ctx.image_shape, spec.shift_px, spec.rotation_deg)

    def apply(self, images, frame_index, time_s):
        for c in self.selected:
            images[c] = _warp(images[c], self.matrix)


@dataclass(frozen=True)
class ReferenceDrift(EffectSpec):
    """Gel ageing: the rest image slowly departs from the stored reference frame.

    The particles creep (an image shift growing at `creep_px_per_s`) and the gel dims (brightness falls by the
    fraction `dimming_per_s` each second, linearly, never below zero). Time counts from the effect's first frame.
    """

    name: ClassVar[str] = "reference_drift"
    stage: ClassVar[int] = OPTICS
    creep_px_per_s: tuple[float, float] = (0.0, 0.0)
    dimming_per_s: float = 0.0

    def bind(self, ctx, rng):
        return _ReferenceDrift(self, ctx)


class _ReferenceDrift(BoundEffect):
    def __init__(self, spec: ReferenceDrift, ctx: EffectContext):
        super().__init__(spec, ctx)
        self.start_s = (spec.frames[0] if spec.frames else 0) / ctx.frame_rate_hz
        self.shape = ctx.image_shape
        self.creep = np.asarray(spec.creep_px_per_s, dtype=np.float64)
        self.shifts = bool(np.any(self.creep != 0.0))

    def apply(self, images, frame_index, time_s):
        elapsed = max(0.0, time_s - self.start_s)
        gain = max(0.0, 1.0 - self.spec.dimming_per_s * elapsed)
        matrix = _warp_matrix(self.shape, self.creep * elapsed, 0.0) if self.shifts else None
        for c in self.selected:
            if matrix is not None:
                images[c] = _warp(images[c], matrix)
            images[c] *= gain


@dataclass(frozen=True)
class DefocusBlur(EffectSpec):
    """The lens out of focus: a Gaussian blur of `sigma_px` model-image pixels."""

    name: ClassVar[str] = "defocus_blur"
    stage: ClassVar[int] = OPTICS
    sigma_px: float = 1.0

    def bind(self, ctx, rng):
        return _DefocusBlur(self, ctx)


class _DefocusBlur(BoundEffect):
    def apply(self, images, frame_index, time_s):
        for c in self.selected:
            images[c] = defocus(images[c], self.spec.sigma_px)


def defocus(image: np.ndarray, sigma_px: float) -> np.ndarray:
    """One camera image (H, W), float32 or uint8, seen out of focus: a Gaussian blur of `sigma_px` pixels, the kernel
    cut at 3 sigma, edges replicated. The same dtype comes back."""
    ksize = 2 * math.ceil(3.0 * sigma_px) + 1
    return cv2.GaussianBlur(image, (ksize, ksize), sigma_px, borderType=cv2.BORDER_REPLICATE)


# --- LIGHT ----------------------------------------------------------------------------------------------------------

class _Gain(BoundEffect):
    """Multiplies each selected camera's image by a gain; subclasses say which gain each frame."""

    def gains(self, frame_index: int, time_s: float) -> np.ndarray:
        raise NotImplementedError

    def apply(self, images, frame_index, time_s):
        gains = self.gains(frame_index, time_s)
        if self.all_cameras:
            images *= gains[:, None, None]
        else:
            images[self.selected] *= gains[self.selected, None, None]


@dataclass(frozen=True)
class IlluminationDrift(EffectSpec):
    """LED brightness wandering slowly: gain 1 + amplitude sin(2 pi t / period + phase), one phase per camera."""

    name: ClassVar[str] = "illumination_drift"
    stage: ClassVar[int] = LIGHT
    amplitude: float = 0.1
    period_s: float = 10.0

    def bind(self, ctx, rng):
        return _IlluminationDrift(self, ctx, rng.uniform(0.0, 2.0 * math.pi, len(ctx.camera_ids)))


class _IlluminationDrift(_Gain):
    def __init__(self, spec: IlluminationDrift, ctx: EffectContext, phases: np.ndarray):
        super().__init__(spec, ctx)
        self.phases = phases

    def gains(self, frame_index, time_s):
        return (1.0 + self.spec.amplitude * np.sin(2.0 * math.pi * time_s / self.spec.period_s + self.phases)
                ).astype(np.float32)


@dataclass(frozen=True)
class LedFlicker(EffectSpec):
    """LED flicker (PWM beating with the exposure): each frame, each camera's gain is uniform in 1 +- amplitude."""

    name: ClassVar[str] = "led_flicker"
    stage: ClassVar[int] = LIGHT
    amplitude: float = 0.05

    def bind(self, ctx, rng):
        return _LedFlicker(self, ctx, rng)


class _LedFlicker(_Gain):
    def __init__(self, spec: LedFlicker, ctx: EffectContext, rng: np.random.Generator):
        super().__init__(spec, ctx)
        self.rng = rng
        self.n = len(ctx.camera_ids)

    def gains(self, frame_index, time_s):
        return (1.0 + self.spec.amplitude * self.rng.uniform(-1.0, 1.0, self.n)).astype(np.float32)


@dataclass(frozen=True)
class ExposureSaturation(EffectSpec):
    """Over-exposure: the image is multiplied by `gain` (scenes take (0, 100]; above 1 bright particles clip at 255,
    below 1 it is an under-exposure)."""

    name: ClassVar[str] = "exposure_saturation"
    stage: ClassVar[int] = LIGHT
    gain: float = 2.0

    def bind(self, ctx, rng):
        return _Exposure(self, ctx)


class _Exposure(_Gain):
    def __init__(self, spec: ExposureSaturation, ctx: EffectContext):
        super().__init__(spec, ctx)
        self._gains = np.full(len(ctx.camera_ids), spec.gain, dtype=np.float32)

    def gains(self, frame_index, time_s):
        return self._gains


# --- SENSOR ---------------------------------------------------------------------------------------------------------

@dataclass(frozen=True)
class SensorNoise(EffectSpec):
    """Read and shot noise of the image sensor as additive Gaussian noise of `sigma` grey levels."""

    name: ClassVar[str] = "sensor_noise"
    stage: ClassVar[int] = SENSOR
    sigma: float = 1.0

    def bind(self, ctx, rng):
        return _SensorNoise(self, ctx, rng)


class _SensorNoise(BoundEffect):
    """Noise from a pool drawn once: each frame adds the window of the pool that starts at a random offset.

    The offsets are drawn uniformly and independently for every frame, which makes the noise cost one addition per
    pixel. Two frames with different offsets share pool samples only at different pixels, so a pixel's noise in
    them is independent; but two frames get the same offset, and then the very same noise field, with probability
    1 / (number of offsets): about 1e-6 for four 128 x 128 images, i.e. about a thousand pairs of identical noise
    fields among the 46200 frames of paper_grid.
    """

    def __init__(self, spec: SensorNoise, ctx: EffectContext, rng: np.random.Generator):
        super().__init__(spec, ctx)
        self.rng = rng
        self.shape = (len(self.selected), *ctx.image_shape)
        self.size = int(np.prod(self.shape))
        pool_size = max(NOISE_POOL_SAMPLES, 4 * self.size)
        self.pool = rng.standard_normal(pool_size, dtype=np.float32) * np.float32(spec.sigma)

    def apply(self, images, frame_index, time_s):
        start = int(self.rng.integers(0, len(self.pool) - self.size + 1))
        noise = self.pool[start:start + self.size].reshape(self.shape)
        if self.all_cameras:
            images += noise
        else:
            images[self.selected] += noise


# --- TRANSPORT ------------------------------------------------------------------------------------------------------

@dataclass(frozen=True)
class CameraDropout(EffectSpec):
    """A camera that stops delivering: `mode` "black" sends black frames, "frozen" repeats its last good frame
    (black if it never sent one). Either way the frame's camera_ok is False for it. `cameras` is required."""

    name: ClassVar[str] = "camera_dropout"
    stage: ClassVar[int] = TRANSPORT
    mode: str = "black"

    def bind(self, ctx, rng):
        return _CameraDropout(self, ctx)


class _CameraDropout(BoundEffect):
    """Acts on the quantised uint8 images and the camera_ok flags (see `apply_transport`)."""

    def apply_transport(self, images: np.ndarray, camera_ok: np.ndarray, frame_index: int,
                        delivered: np.ndarray) -> None:
        """`delivered`: each camera's last frame delivered good (EffectChain), which "frozen" repeats."""
        if not self.spec.active(frame_index):
            return
        images[self.selected] = 0 if self.spec.mode == "black" else delivered[self.selected]
        camera_ok[self.selected] = False


EFFECTS: dict[str, type[EffectSpec]] = {cls.name: cls for cls in (
    SensorNoise, DefocusBlur, IlluminationDrift, LedFlicker, ExposureSaturation, CameraDropout, ReferenceDrift,
    CameraMisalignment)}

#: Largest frame index an effect's `frames` may name: the most frames a scene may have (scene.MAX_FRAMES).
MAX_EFFECT_FRAME = 10_000_000

_RULES = {
    # key: (kind, check, what the user should write)
    "sigma": ("number", lambda v: 0 < v <= 255, "in (0, 255] grey levels"),
    "sigma_px": ("number", lambda v: 0 < v <= 20, "in (0, 20] pixels"),
    "amplitude": ("number", lambda v: 0 <= v < 1, "in [0, 1) (a fraction of the brightness)"),
    # A period of 1e-310 s made sin(inf): NaN brightness, black frames flagged good (found in review).
    "period_s": ("number", lambda v: v >= 1e-3, ">= 0.001 seconds"),
    "gain": ("number", lambda v: 0 < v <= 100, "in (0, 100]"),
    "rotation_deg": ("number", lambda v: abs(v) <= 45, "within +-45 degrees"),
    "dimming_per_s": ("number", lambda v: 0 <= v <= 1, "in [0, 1] (fraction of the brightness lost per second)"),
    "shift_px": ("pair", lambda v: all(abs(x) <= 64 for x in v), "[dx, dy] within +-64 pixels"),
    "creep_px_per_s": ("pair", lambda v: all(abs(x) <= 64 for x in v), "[dx, dy] within +-64 pixels per second"),
    "mode": ("choice", ("black", "frozen"), "'black' or 'frozen'"),
}


def parse_effect(node, where: str) -> EffectSpec:
    """An effect spec from one entry of a scene's `effects` list: a mapping with `type` and that effect's keys."""
    if not isinstance(node, dict) or "type" not in node:
        raise SceneError(f"{where}: an effect must be a mapping with a 'type' key (one of {sorted(EFFECTS)}), "
                         f"got {node!r}")
    kind = node["type"]
    if not isinstance(kind, str) or kind not in EFFECTS:  # a list or a mapping is no key of EFFECTS (TypeError)
        raise SceneError(f"{where}: unknown effect type {kind!r}; known effects are {sorted(EFFECTS)}")
    cls = EFFECTS[kind]
    allowed = [f.name for f in fields(cls)]
    values = {}
    for key, value in node.items():
        if key == "type":
            continue
        if key not in allowed:
            raise SceneError(f"{where}: effect {kind!r} has no key {key!r}; its keys are {allowed}")
        values[key] = _effect_value(kind, key, value, where)
    if kind == "camera_dropout" and "cameras" not in values:
        raise SceneError(f"{where}: effect 'camera_dropout' needs 'cameras' (the ids of the cameras that drop)")
    return cls(**values)


def _effect_value(kind: str, key: str, value, where: str):
    here = f"{where}: effect {kind!r} key {key!r}"
    if key == "cameras":
        if not (isinstance(value, list) and value and all(isinstance(c, str) for c in value)):
            raise SceneError(f"{here} must be a non-empty list of camera ids, got {value!r}")
        return tuple(value)
    if key == "frames":  # at most MAX_EFFECT_FRAME: 10**400 overflowed a float when the effect was bound
        if not (isinstance(value, list) and len(value) == 2 and all(is_whole_number(v, 0) for v in value)
                and value[0] < value[1] <= MAX_EFFECT_FRAME):
            raise SceneError(f"{here} must be [first, stop) frame indices with 0 <= first < stop <= "
                             f"{MAX_EFFECT_FRAME}, got {value!r}")
        return (value[0], value[1])
    kind_of_value, check, expected = _RULES[key]
    if kind_of_value == "choice":
        if value not in check:
            raise SceneError(f"{here} must be {expected}, got {value!r}")
        return value
    if kind_of_value == "pair":
        if not (isinstance(value, list) and len(value) == 2 and all(is_number(v) for v in value)) or not check(value):
            raise SceneError(f"{here} must be {expected}, got {value!r}")
        return (float(value[0]), float(value[1]))
    if not is_number(value) or not check(value):
        raise SceneError(f"{here} must be a finite number {expected}, got {value!r}")
    return float(value)


@dataclass
class EffectChain:
    """The bound effects of one stream, in imaging-chain order (see the module docstring)."""

    image_effects: list[BoundEffect] = field(default_factory=list)
    transport_effects: list[_CameraDropout] = field(default_factory=list)
    #: Each camera's last frame that left the transport stage good: what a frozen camera repeats. One copy for all
    #: dropouts: each kept its own, so a camera frozen while another dropout blacked it out repeated a frame never
    #: delivered, or froze on black after good ones (found in review).
    delivered: np.ndarray | None = None

    def apply_images(self, images: np.ndarray, frame_index: int, time_s: float) -> None:
        for effect in self.image_effects:
            if effect.spec.active(frame_index):
                effect.apply(images, frame_index, time_s)

    def apply_transport(self, images: np.ndarray, camera_ok: np.ndarray, frame_index: int) -> None:
        if not self.transport_effects:
            return
        if self.delivered is None:
            self.delivered = np.zeros_like(images)  # frozen before any good frame: black
        for effect in self.transport_effects:
            effect.apply_transport(images, camera_ok, frame_index, self.delivered)
        self.delivered[camera_ok] = images[camera_ok]


def bind_effects(specs: Sequence[EffectSpec], ctx: EffectContext) -> EffectChain:
    """Bind each spec to the stream; effect i draws its random numbers from its own stream seeded [seed, 1, i]."""
    bound = [(spec.stage, i, spec.bind(ctx, np.random.default_rng([ctx.seed, 1, i]))) for i, spec in enumerate(specs)]
    bound.sort(key=lambda item: (item[0], item[1]))
    chain = EffectChain()
    for stage, _, effect in bound:
        (chain.transport_effects if stage == TRANSPORT else chain.image_effects).append(effect)
    return chain
