"""The simulated sensor: scene contacts -> ground-truth bin forces -> particle motion -> camera images -> effects.

    sim = Simulator(load_sensor())
    for frame in sim.stream(load_scene("paper_grid")):
        frame.images, frame.bin_forces_n, frame.camera_ok

`stream` is a generator: each frame's arrays are new and nothing is kept from one frame to the next except
what an effect needs (the last good image of a camera that may freeze), so memory does not grow with the
number of frames.
"""

from __future__ import annotations

from collections.abc import Iterator, Sequence
from dataclasses import dataclass

import numpy as np

from tactile_description import SensorConfigError, SensorDescription, load_sensor
from tactile_sim.contact import GROUND_TRUTH_MODELS, Contact, ground_truth_model
from tactile_sim.effects import EffectChain, bind_effects
from tactile_sim.elastic import GelDisplacement
from tactile_sim.particles import ParticleField, generate_particles
from tactile_sim.render import Optics, ParticleRenderer
from tactile_sim.scene import Scene

#: The fewest grey levels a camera's particles must add somewhere to its reference image: a camera that sees the gel
#: gets 180-235 (the reference sensor's and skin_3x3's cameras), one 60 mm beside the surface or 30 mm below it 37-39,
#: one 300 mm beside it 1.8 and one with a principal point far outside its capture 0.
MIN_PARTICLE_CONTRAST = 10.0


@dataclass(frozen=True)
class Frame:
    """One simulated frame of every camera, with its ground truth."""

    index: int
    time_s: float
    contacts: tuple[Contact, ...]
    images: np.ndarray        # (C, H, W) uint8, after the scene's effects
    bin_forces_n: np.ndarray  # (rows, cols, 3) float32 newtons: fx, fy, fz (compression positive)
    camera_ok: np.ndarray     # (C,) bool: False for a camera that dropped out or froze in this frame


def quantize(images: np.ndarray) -> np.ndarray:
    """float32 grey levels -> uint8 as a camera does: round to nearest, clip to 0..255 (in place on `images`)."""
    np.add(images, 0.5, out=images)
    np.clip(images, 0.0, 255.0, out=images)
    return images.astype(np.uint8)


class Simulator:
    """The sensor of one description: particles, gel, cameras and a ground-truth contact model.

    Building it costs about a second (particle kernels, rest images); frames are then cheap.
    """

    def __init__(self, sensor: SensorDescription | None = None, ground_truth: str = GROUND_TRUTH_MODELS[0],
                 optics: Optics | None = None):
        self.sensor = sensor if sensor is not None else load_sensor()
        self.particles: ParticleField = generate_particles(self.sensor)
        self.renderer = ParticleRenderer(self.sensor, self.particles, "output", optics)
        self._check_cameras_see_particles()
        self.ground_truth = ground_truth_model(self.sensor, ground_truth)
        self.gel = GelDisplacement(self.sensor, self.particles.positions_m)
        self._reference_u8 = quantize(self.renderer.reference.copy())
        self._reference_u8.setflags(write=False)

    def _check_cameras_see_particles(self) -> None:
        """SensorConfigError for a camera whose particles add less than MIN_PARTICLE_CONTRAST grey levels anywhere to
        its reference image: it sees no particle, and its frames are noise. A typo in a lens or a camera's position
        (cx 1600 for 160, a camera 300 mm beside the surface) gave blank images, a data set and a model trained on
        them, without a word (walkthrough)."""
        contrast = (self.renderer.reference - self.renderer.background).reshape(self.renderer.n_cameras, -1).max(1)
        blind = [f"{cam.camera_id} ({level:.2g})" for cam, level in zip(self.sensor.cameras, contrast, strict=True)
                 if level < MIN_PARTICLE_CONTRAST]
        if blind:
            raise SensorConfigError(f"{self.sensor.source}: camera(s) {', '.join(blind)} see no particle of the gel: "
                                    "their particles add at most the grey levels in brackets to their images (the "
                                    "reference sensor's cameras: 180 to 235); check their position_mm and yaw_deg, "
                                    "and the lens (fx, fy, cx, cy in capture pixels, distortion)")

    @property
    def camera_ids(self) -> tuple[str, ...]:
        return self.sensor.camera_ids

    @property
    def image_shape(self) -> tuple[int, int]:
        """(H, W) of each model image."""
        return self.renderer.height, self.renderer.width

    def reference_images(self) -> np.ndarray:
        """(C, H, W) uint8: every camera at rest (no contact, no effects), the frames the model subtracts."""
        return self._reference_u8.copy()

    def bin_forces(self, contacts: Sequence[Contact]) -> np.ndarray:
        """(rows, cols, 3) float32 ground truth of the contacts (no contact -> zeros)."""
        return self.ground_truth.bin_forces(list(contacts)).astype(np.float32)

    def render(self, bin_forces_n: np.ndarray) -> np.ndarray:
        """(C, H, W) float32 clean images (before effects and quantisation) of the gel loaded by `bin_forces_n`."""
        if not np.any(bin_forces_n):
            return self.renderer.reference.copy()
        return self.renderer.render_displaced(self.gel.displacements_m(bin_forces_n))

    def particle_positions_m(self, bin_forces_n: np.ndarray) -> np.ndarray:
        """(N, 3) particle positions under `bin_forces_n` (for inspection and tests)."""
        return self.particles.positions_m + self.gel.displacements_m(bin_forces_n)

    def stream(self, scene: Scene, frames: int | None = None) -> Iterator[Frame]:
        """The frames of `scene` (or of its first `frames` frames), one at a time. The scene is checked here, before
        the first frame (SceneError: Scene.check_playable with this simulator's ground truth, of those frames: a scene
        whose later random presses find no room plays its first ones)."""
        if frames is not None:
            scene = scene.limited(frames)
        scene.check_playable(self.sensor, self.ground_truth)
        return self._frames(scene, bind_effects(scene.effects, scene.effect_context(self.sensor)))

    def _frames(self, scene: Scene, effects: EffectChain) -> Iterator[Frame]:
        period_s = 1.0 / self.sensor.frame_rate_hz
        n_cameras = self.sensor.n_cameras
        for index, contacts in enumerate(scene.contacts(self.sensor)):
            time_s = index * period_s
            forces = self.bin_forces(contacts)
            images = self.render(forces)
            effects.apply_images(images, index, time_s)
            images_u8 = quantize(images)
            camera_ok = np.ones(n_cameras, dtype=bool)
            effects.apply_transport(images_u8, camera_ok, index)
            yield Frame(index=index, time_s=time_s, contacts=contacts, images=images_u8, bin_forces_n=forces,
                        camera_ok=camera_ok)
