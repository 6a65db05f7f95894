"""Small synthetic frames and a tiny model configuration for fast tests of the learning code.

The synthetic "sensor" has two 16 x 16 cameras and a 3 x 4 bin grid; a frame presses one bin, and each camera
sees a bright blob whose position follows the pressed bin and whose brightness follows the force, so a model
can learn the mapping in a few epochs. Tests that need the real sensor use the simulator instead.
"""

import numpy as np
import pytest

from tactile_fusion.data import FrameSet
from tactile_fusion.model import ForceFusionNet, ModelConfig

ROWS, COLS, SIZE = 3, 4, 16
CAMERAS = ("left", "right")


def synthetic_frames(n: int, seed: int = 0) -> FrameSet:
    rng = np.random.default_rng(seed)
    reference = rng.integers(60, 200, size=(len(CAMERAS), SIZE, SIZE), dtype=np.uint8)
    images = np.repeat(reference[None], n, axis=0).astype(np.int16)
    forces = np.zeros((n, ROWS, COLS, 3), dtype=np.float32)
    yy, xx = np.mgrid[0:SIZE, 0:SIZE]
    for i in range(n):
        r, c, load = rng.integers(ROWS), rng.integers(COLS), rng.uniform(0.0, 1.0)
        forces[i, r, c] = (0.02 * load, -0.01 * load, 0.3 * load)
        for cam in range(len(CAMERAS)):
            cy, cx = 2 + 4 * r, 2 + 3 * c + 3 * cam
            images[i, cam] += (80 * load * np.exp(-((yy - cy) ** 2 + (xx - cx) ** 2) / 4.0)).astype(np.int16)
    images = np.clip(images, 0, 255).astype(np.uint8)
    return FrameSet(images=images, bin_forces_n=forces, reference=reference,
                    camera_ok=np.ones((n, len(CAMERAS)), dtype=bool), camera_ids=CAMERAS, scene="synthetic", seed=seed)


@pytest.fixture
def tiny_config() -> ModelConfig:
    return ModelConfig(image_size=SIZE, conv_channels=(4, 4), hidden_features=16, camera_features=12, dropout=0.1,
                       fusion_rank=None)


@pytest.fixture
def frames() -> FrameSet:
    return synthetic_frames(48)


@pytest.fixture(scope="session")
def fz_only_copy():
    """A function: a dense-fusion model -> the same model estimating Fz alone (its fusion rows of Fz, the rest of its
    weights as they are), so the Fz it outputs is exactly the original's."""
    def copy(model: ForceFusionNet) -> ForceFusionNet:
        state = model.state_dict()
        for name in ("fusion.expand.weight", "fusion.expand.bias"):
            state[name] = state[name][2::3]
        fz = ForceFusionNet(model.config, model.camera_ids, model.rows, model.cols, model.force_scale_n, ("fz",))
        fz.load_state_dict(state)
        return fz.eval()
    return copy


@pytest.fixture(scope="session")
def make_frames():
    """The synthetic frame maker itself, for fixtures that need their own frames."""
    return synthetic_frames
