"""Training loop: RMSE loss that stays finite, Adam, early stopping on the validation split, seeded and
reproducible, tqdm progress bars, checkpoints that resume to exactly the same weights.

The loop is generic over a `BatchSource` (what a batch of frame indices becomes: normalised predictions and
targets), so full training (difference images through the whole network) and modular recalibration (cached
features of the frozen CNN, see recalibration.py) share it.
"""

from __future__ import annotations

import copy
import time
from collections.abc import Callable, Iterable, Iterator
from contextlib import contextmanager
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from typing import Protocol

import numpy as np
import torch
from tqdm import tqdm

from tactile_description import FORCE_COMPONENTS
from tactile_description.command_line import one_line
from tactile_description.value_checks import is_number, is_whole_number
from tactile_fusion.artifacts import write_torch_file
from tactile_fusion.data import FrameDataError, FrameSet, check_finite_targets, forces_sha256
from tactile_fusion.fz_threshold import fit_threshold_and_fusion
from tactile_fusion.least_squares import RIDGES, fit_fusion
from tactile_fusion.model import ForceFusionNet, ModelConfig, checked_components
from tactile_fusion.sources import Augmentation, CachedSource, ImageSource, normalised_rmse

#: Precisions of the gradient steps on cached features (head phase, recalibration). "bf16": the forward pass of each
#: step under torch.autocast in bfloat16: the matrix products take bf16 inputs and sum in float32, and their bf16
#: outputs go on through batch norm (whose running statistics therefore come from bf16 activations), ReLU and dropout
#: into the fusion; the weights, Adam, the loss, validation and the least-squares fit stay float32. On a CPU with bf16
#: instructions a head step takes 5.1 instead of 8.7 ms with the same accuracy (docs/learning.md). "fp32": all in
#: float32. "auto": bf16 where the CPU has the instructions (`native_bf16`), float32 elsewhere.
STEP_PRECISIONS = ("auto", "bf16", "fp32")


def native_bf16(device: torch.device | None = None) -> bool:
    """Whether `device` (None: the CPU) multiplies bfloat16 matrices in hardware: a CPU with AVX512-BF16 or AMX, an
    NVIDIA GPU from Ampere on. Elsewhere bf16 is emulated and slower than float32. (torch.cpu's private queries: a
    torch without them counts as without bf16.)"""
    if device is not None and device.type == "cuda":
        # bf16 tensor cores from compute capability 8 (Ampere) on; torch.cuda.is_bf16_supported() also counts the
        # emulation of older GPUs, which is slower than float32 (review)
        return torch.cuda.get_device_properties(device).major >= 8
    cpu = torch.cpu
    return bool(getattr(cpu, "_is_avx512_bf16_supported", lambda: False)()
                or getattr(cpu, "_is_amx_tile_supported", lambda: False)())


#: Where the gradient steps of training run (TrainConfig.device): "cpu", or "cuda" / "cuda:N" for a GPU.
DEVICE_KINDS = ("cpu", "cuda")


def parsed_device(name: str) -> torch.device:
    """TrainConfig.device as a torch.device; ValueError for anything but "cpu", "cuda" and "cuda:N" (whether that
    GPU exists is `training_device`'s question)."""
    refusal = ValueError(f"TrainConfig.device must be 'cpu', 'cuda' or 'cuda:N', got {name!r}")
    try:
        device = torch.device(name) if isinstance(name, str) else None  # torch takes 0 for cuda:0, or refuses it
    except RuntimeError as exc:
        raise refusal from exc
    if device is None or device.type not in DEVICE_KINDS or (device.type == "cpu" and device.index is not None):
        raise refusal
    return device


def training_device(name: str) -> torch.device:
    """The torch.device that TrainConfig.device names, checked to exist here: a ValueError that says what this machine
    has, before any frame is simulated, rather than a CUDA error from the first step."""
    device = parsed_device(name)
    if device.type == "cuda":
        if not torch.cuda.is_available():
            raise ValueError(f"TrainConfig.device {name!r}: this torch ({torch.__version__}) sees no CUDA GPU: train "
                             "on 'cpu', or install a CUDA build of torch on a machine with an NVIDIA GPU")
        if device.index is not None and device.index >= torch.cuda.device_count():
            raise ValueError(f"TrainConfig.device {name!r}: this machine has {torch.cuda.device_count()} CUDA GPU(s), "
                             "numbered from 0")
    return device


#: The largest TrainConfig.seed: numpy's and torch's generators take seeds derived from it (seed * 100003 + epoch for
#: an epoch's dropout masks must fit torch's 64-bit seed); a negative seed failed in numpy, 2e14 in torch, both with a
#: traceback once the data had been simulated.
MAX_SEED = 2**32 - 1


@dataclass(frozen=True)
class TrainConfig:
    """How to train. Two runs with the same config, data and seed on the same kind of CPU give the same weights (the
    last bits of the sums depend on the instruction set, and `head_precision` "auto" on whether it has bf16); on a GPU
    (`device`) they do not (see fit).

    Training has three phases (`train_phases`): end-to-end for up to `max_epochs`; then the head (fully connected layers
    and fusion) alone for up to `head_epochs` on cached conv features (an epoch over the frames and their imperfect copy
    costs about a ninth of an end-to-end one, a sixteenth with its steps in bfloat16, `head_precision`); then the exact
    least-squares fit of the linear fusion layer (least_squares.py). The end-to-end phase stops early after `patience`
    epochs without a better validation RMSE; the head phase runs all its epochs (`head_phase`). Neither uses the model's
    dropout of 0.1 by default (`end_to_end_dropout`, `head_dropout`; None: the model's rate): without it the end-to-end
    phase reached a validation RMSE 11 % lower after its four epochs, and the model, after the head cycles and the Fz
    threshold, 1.8 % less error per bin and 2.6 % less in total on the test split (docs/learning.md). The head phase
    learns from the training frames and from a copy of them seen through camera imperfections (`head_augmentation`: one
    camera askew on a `head_misalign_fraction` share, defocus blur up to `head_blur_sigma_px` on a `head_blur_fraction`
    share, extra sensor noise up to `head_noise_sigma` grey levels on all). Measured against the dropout of 0.1 on clean
    frames alone that this replaced, noise and blur alone: the same error in distribution; on the effects scene six of
    eight windows lose half to four fifths of their total-force error, the misaligned camera's doubles, which the camera
    askew on a tenth of the frames cuts six-fold (docs/learning.md). The least-squares fit uses the frames alone: fitted
    to the copy as well, the fusion gave 3 % more error per bin and 10 % more in total in distribution for 5 % less
    under effects. Modular recalibration (recalibration.py) trains like the head phase, on clean frames:
    `recalibration_phase`.

    The epoch counts are sized for the default scene (paper_grid, 32340 training frames, 4 x 2022 end-to-end
    steps; the head phase's 5 epochs over the frames, their imperfect copy and three further draws of the scene, 203280
    samples, make 5 x 3177 steps in each of its `head_cycles` cycles, about as many as 6 epochs of 2455 with two draws,
    the default until 2026-11-28, 9 of 1733 with one or 15 without any).
    Three head cycles after 8 end-to-end epochs reached 2.99 mN per bin where one after 13 reached 3.25
    (docs/learning.md): the head, not the conv trunk, was short of training. Then the head was short of data: the
    same steps over twice the presses (the epochs halved) reached 2.68 mN on the same test frames. With the head's
    steps in bf16, a fourth cycle costs less than the third did in float32: 2.53 against 2.62 mN; a fifth, judged
    after its fit (train_phases), 2.47. More presses for the head alone (a further draw of the scene,
    pipeline.further_draws), in the same number of steps: 2.30; a second draw, in the same number of steps on the
    five-block trunk: 1.974 against 2.024; a third, in about the same number of steps and without dropout end to end:
    1.897 against 1.939 (docs/learning.md).
    """

    max_epochs: int = 4
    batch_size: int = 16          # frames per step; each brings all its cameras through the CNN
    end_to_end_dropout: float | None = 0.0  # dropout of the fully connected layers end to end; None: the model's
    learning_rate: float = 2e-3
    patience: int = 6             # early stopping: epochs without a better validation RMSE
    min_learning_rate: float = 1e-5  # the learning rate follows a cosine from learning_rate down to this
    seed: int = 0
    loss_eps: float = 1e-8        # RMSE = sqrt(MSE + eps): finite gradient at zero error
    head_epochs: int = 5          # second phase: conv trunk frozen, head trained on cached features
    head_learning_rate: float = 4e-3
    head_batch_size: int = 64     # frames per head step: a head step is cheap, larger batches use the cores better
    head_dropout: float | None = 0.0  # dropout of the fully connected layers in the head phase; None: the model's
    head_noise_sigma: float = 1.2  # head phase's imperfect copy: extra sensor noise up to this (grey levels) ...
    head_blur_fraction: float = 0.2  # ... and defocus blur on this share of the frames ...
    head_blur_sigma_px: float = Augmentation.blur_sigma_px  # ... of up to this sigma (pixels) ...
    head_misalign_fraction: float = 0.1  # ... and one camera knocked askew on this share ...
    head_misalign_shift_px: float = Augmentation.misalign_shift_px  # ... shifted by up to this per axis (pixels) ...
    head_misalign_rotation_deg: float = Augmentation.misalign_rotation_deg  # ... and turned by up to this (degrees);
    # fractions and noise 0: no copy
    head_cycles: int = 5          # head phase, least-squares fit, repeated from there with a new copy this often
    head_precision: str = "auto"  # of the steps on cached features (head phase, recalibration), see STEP_PRECISIONS
    recalibration_epochs: int = 7  # modular recalibration: epochs of the last layers on cached features
    device: str = "cpu"           # where the gradient steps run (`fit`): "cpu", or "cuda" / "cuda:N", a GPU

    def __post_init__(self):
        if not (is_whole_number(self.seed, 0) and self.seed <= MAX_SEED):
            raise ValueError(f"TrainConfig.seed must be a whole number from 0 to {MAX_SEED}, got {self.seed!r}")
        if not is_whole_number(self.head_epochs, 0):
            raise ValueError(f"TrainConfig.head_epochs must be a whole number >= 0, got {self.head_epochs!r}")
        for name in ("max_epochs", "batch_size", "head_batch_size", "patience", "recalibration_epochs", "head_cycles"):
            if not is_whole_number(getattr(self, name)):
                raise ValueError(f"TrainConfig.{name} must be a whole number >= 1, got {getattr(self, name)!r}")
        for name in ("learning_rate", "head_learning_rate", "loss_eps"):
            if not (is_number(getattr(self, name)) and getattr(self, name) > 0):
                raise ValueError(f"TrainConfig.{name} must be a finite number > 0, got {getattr(self, name)!r}")
        if not (is_number(self.min_learning_rate) and self.min_learning_rate >= 0):
            raise ValueError(f"TrainConfig.min_learning_rate must be a finite number >= 0, got "
                             f"{self.min_learning_rate!r}")
        for name in ("end_to_end_dropout", "head_dropout"):
            rate = getattr(self, name)
            if rate is not None and not (is_number(rate) and 0.0 <= rate < 1.0):
                raise ValueError(f"TrainConfig.{name} must be in [0, 1), got {rate!r}")
        if self.head_precision not in STEP_PRECISIONS:
            raise ValueError(f"TrainConfig.head_precision must be one of {list(STEP_PRECISIONS)}, got "
                             f"{self.head_precision!r}")
        parsed_device(self.device)
        try:
            self.head_augmentation()
        except ValueError as exc:
            raise ValueError(str(exc).replace("Augmentation.", "TrainConfig.head_")) from exc

    def check_batch_sizes(self, n_cameras: int) -> None:
        """Raise ValueError unless both batch sizes are large enough for batch normalisation with `n_cameras` cameras
        (`min_batch_frames`): checked before any frame is simulated, not when the phase that uses one starts."""
        needed = min_batch_frames(n_cameras)
        for name in ("batch_size", "head_batch_size"):
            if getattr(self, name) < needed:
                raise ValueError(f"TrainConfig.{name} must be >= {needed} for a {n_cameras}-camera model (batch "
                                 f"normalisation needs two images per batch), got {getattr(self, name)}")

    def head_augmentation(self) -> Augmentation:
        """The camera imperfections of the head phase's copy of the training frames."""
        return Augmentation(self.head_noise_sigma, self.head_blur_fraction, self.head_blur_sigma_px,
                            self.head_misalign_fraction, self.head_misalign_shift_px, self.head_misalign_rotation_deg)

    def head_phase(self) -> TrainConfig:
        """The settings of the head phase: its own epochs, learning rate and batch size, the rest shared.

        The head phase runs all its epochs (patience = its epoch count): it restarts the head at a high
        learning rate, so its validation error first rises above the end-to-end result and only beats it after
        more than `patience` epochs; early stopping would end the phase there and keep the end-to-end weights
        (measured: a 60-epoch head phase stopped after 12 epochs). Its last epoch is kept; the cycle is judged
        after the fit that follows (train_phases).
        """
        return self._on_cached_features(self.head_epochs)

    def recalibration_phase(self) -> TrainConfig:
        """The settings of modular recalibration: the head phase's batch size, learning rate and dropout for
        `recalibration_epochs`, all of them run (the last is kept and judged after the fit, see recalibrate).
        At the model's dropout of 0.1 the trained layers, fitted, lost to the fusion refit alone at every fraction of
        the study's data; at the head's 0 they win with all the data (docs/learning.md).

        Recalibration trains the same kind of layers on cached features as the head phase. Measured on the
        recalibration study's 3-camera base, all the training data of the former 24 x 24 default grid
        (docs/learning.md): with the end-to-end phase's 16-frame batches at 2e-3, 26 epochs took 184 s for 4.19 mN
        per bin; with the head phase's 64 frames at 4e-3, 80 s for 4.13 mN. The default of 7 epochs on the four times
        as large 48 x 48 grid makes about the same number of steps (7 x 506 against 26 x 128).
        """
        return self._on_cached_features(self.recalibration_epochs)

    def _on_cached_features(self, epochs: int) -> TrainConfig:
        """`epochs` epochs, all run, at the head settings: a phase that trains layers on cached features; its
        head_precision resolved to the one its steps use ("bf16" or "fp32"), which its checkpoint records."""
        return replace(self, max_epochs=epochs, learning_rate=self.head_learning_rate,
                       batch_size=self.head_batch_size, patience=max(epochs, 1), head_epochs=0,
                       head_precision=self._resolved_precision())

    def _resolved_precision(self) -> str:
        """head_precision with "auto" decided for the device the steps run on: "bf16" or "fp32"."""
        if self.head_precision == "auto":
            return "bf16" if native_bf16(parsed_device(self.device)) else "fp32"
        return self.head_precision


# Which phase each training setting decides. A checkpoint is resumed only with the same values of the settings that
# decide its phase, so the head settings of an interrupted run may change (its head checkpoints are then refused until
# deleted, but the end-to-end one resumes). Every TrainConfig field is in exactly one of these (tested).
END_TO_END_SETTINGS = ("max_epochs", "batch_size", "learning_rate", "patience", "end_to_end_dropout")
HEAD_SETTINGS = ("head_epochs", "head_learning_rate", "head_batch_size", "head_dropout", "head_noise_sigma",
                 "head_blur_fraction", "head_blur_sigma_px", "head_misalign_fraction", "head_misalign_shift_px",
                 "head_misalign_rotation_deg", "head_precision")
SHARED_SETTINGS = ("min_learning_rate", "seed", "loss_eps")
#: Settings that decide no single phase's result: how many head cycles follow, how long recalibration runs, where the
#: steps run (a phase may resume on another device: its sums then differ in the last bits, as between two kinds of CPU).
NOT_PHASE_SETTINGS = ("head_cycles", "recalibration_epochs", "device")
#: What a phase's checkpoint is compared on: {field of the config that `fit` gets: the setting's name}. The head phase's
#: config (`TrainConfig.head_phase`) carries the head's epochs as max_epochs (and its learning rate and batch size in
#: both places; its patience follows its epochs).
END_TO_END_COMPARED = {k: k for k in END_TO_END_SETTINGS + SHARED_SETTINGS}
HEAD_COMPARED = {"max_epochs": "head_epochs",
                 **{k: k for k in HEAD_SETTINGS + SHARED_SETTINGS if k != "head_epochs"}}


def rmse_loss(prediction: torch.Tensor, target: torch.Tensor, eps: float = 1e-8) -> torch.Tensor:
    """sqrt(mean((prediction - target)^2) + eps).

    d sqrt(m)/dm = 1 / (2 sqrt(m)) is infinite at m = 0 (an exact batch gives NaN gradients, SENSOR_BRIEF
    hazards); with eps the gradient is dm / (2 sqrt(m + eps)), which is 0 when the error is 0. eps = 1e-8 on
    normalised forces moves the loss by at most 1e-4 of the force scale. An empty batch raises ValueError (the mean of
    nothing is NaN).
    """
    if prediction.numel() == 0:
        raise ValueError("rmse_loss: an empty batch has no error")
    return torch.sqrt(torch.mean((prediction - target) ** 2) + eps)


class BatchSource(Protocol):
    """What the training loop needs from data: normalised predictions and targets for frame indices."""

    def __len__(self) -> int: ...

    def predict(self, model: ForceFusionNet, indices: np.ndarray) -> torch.Tensor: ...

    def target(self, indices: np.ndarray) -> torch.Tensor: ...


class CheckpointMismatchError(ValueError):
    """A checkpoint to resume from that another model or other training settings wrote, or that cannot be read (the
    message says what to do)."""


class SettingsMismatchError(CheckpointMismatchError):
    """A checkpoint written with other training settings: `differences` lists (setting, then, now), each setting by
    its TrainConfig name; `describe` names them otherwise (the command line by its options: --epochs, not
    max_epochs)."""

    def __init__(self, path: Path, differences: list[tuple[str, object, object]]):
        self.path = path
        self.differences = differences
        super().__init__(self.describe())

    def describe(self, name: Callable[[str], str] = str) -> str:
        differ = ", ".join(f"{name(setting)} {then!r} (now {now!r})" for setting, then, now in self.differences)
        return (f"checkpoint {self.path} was written with other training settings: {differ}; resume with the same "
                "settings, or delete it and the checkpoints of the phases after it")


@dataclass
class TrainResult:
    initial_val_rmse: float         # normalised validation RMSE before the first epoch
    best_epoch: int                 # 1-based epoch with the lowest validation RMSE (0: none better than the start)
    best_val_rmse: float            # normalised validation RMSE of that epoch
    epochs_run: int
    wall_time_s: float              # training time, summed over resumed runs
    stopped_early: bool
    history: list = field(default_factory=list)  # per epoch: train/val RMSE (normalised), learning rate
    step_precision: str = "fp32"    # of the training steps' forward pass: "bf16" or "fp32"
    kept_epoch: int = 0             # epoch whose weights the phase returned: best_epoch, or the last one (see fit)

    def to_dict(self) -> dict:
        return asdict(self)


def build_model(config: ModelConfig, camera_ids, rows: int, cols: int, force_scale_n: torch.Tensor,
                seed: int, components: tuple[str, ...] = FORCE_COMPONENTS) -> ForceFusionNet:
    """A freshly initialised model; the initial weights depend only on `seed`."""
    torch.manual_seed(seed)
    return ForceFusionNet(config, camera_ids, rows, cols, force_scale_n, components)


def min_batch_frames(n_cameras: int) -> int:
    """The fewest frames per training step for a model of `n_cameras` cameras: batch normalisation in training mode
    needs two samples per batch, and each frame brings one per camera."""
    return -(-2 // n_cameras)


def epoch_batches(n: int, batch_size: int, seed: int, epoch: int, min_batch: int = 1) -> list[np.ndarray]:
    """The shuffled batches of one epoch, a function of (seed, epoch) only, so a resumed run repeats them.

    A last batch smaller than `min_batch` joins the one before it.
    """
    order = np.random.default_rng([seed, epoch]).permutation(n)
    batches = [order[i:i + batch_size] for i in range(0, n, batch_size)]
    if len(batches) > 1 and len(batches[-1]) < min_batch:
        batches[-2:] = [np.concatenate(batches[-2:])]
    return batches


def fit(model: ForceFusionNet, train: BatchSource, val: BatchSource, config: TrainConfig,
        checkpoint_path: str | Path | None = None, resume: bool = False, progress: bool = False,
        on_epoch_end: Callable[[int, dict], None] | None = None, desc: str = "train",
        compared: dict[str, str] | None = None, data: dict | None = None, step_precision: str = "fp32",
        keep: str = "best") -> TrainResult:
    """Train the parameters of `model` that require gradients; keep the weights of the best validation epoch
    (keep="best", or of the start if no epoch beat it), or of the last epoch (keep="last").

    step_precision: "bf16" runs the forward pass of each training step in bfloat16, "fp32" in float32 (see
    STEP_PRECISIONS; validation stays float32). A phase config's resolved head_precision is one of them.

    checkpoint_path: written after every epoch (atomically); with `resume`, training continues from it and
    ends with the same weights as an uninterrupted run (with the same torch thread count). It is refused if it was
    written with other values of the `compared` settings ({config field: name in the message}; None: all of them)
    or on top of other frozen weights than the model's (the phase before it changed since), or on other data (`data`,
    see `data_identity`; a checkpoint that records none is not checked). on_epoch_end(epoch, record) is called after
    each epoch's checkpoint (an exception raised there interrupts training cleanly).

    The steps run on config.device: the model goes there for the phase and back to the CPU when fit returns or raises
    (the sources hand each batch to the model's device). On a GPU a run is not the CPU's run: its dropout masks come
    from CUDA's generator (another draw), and cuDNN convolves in TF32. Nor are two GPU runs, or a run and its resumed
    copy, equal to the bit: cuDNN's backward algorithms need not add in a fixed order (torch.backends.cudnn.
    deterministic is off).
    """
    if step_precision not in ("bf16", "fp32"):
        raise ValueError(f"fit: step_precision must be 'bf16' or 'fp32', got {step_precision!r}")
    if keep not in ("best", "last"):
        raise ValueError(f"fit: keep must be 'best' or 'last', got {keep!r}")
    params = [p for p in model.parameters() if p.requires_grad]
    if not params:
        raise ValueError("fit: the model has no trainable parameters")
    if len(train) < 1 or len(val) < 1:
        raise ValueError(f"fit: need at least one training and one validation frame, got {len(train)} and "
                         f"{len(val)}")
    config.check_batch_sizes(model.n_cameras)
    min_batch = min_batch_frames(model.n_cameras)
    if len(train) < min_batch:
        raise FrameDataError(f"fit: a {model.n_cameras}-camera model needs at least {min_batch} training frames "
                             f"(batch normalisation needs two images per batch), got {len(train)}; give more frames")
    device = training_device(config.device)
    try:
        model.to(device)  # moves the parameters in place: `params` are the optimiser's on the device
        return _fit_on(model, params, train, val, config, device, min_batch, checkpoint_path, resume, progress,
                       on_epoch_end, desc, compared, data, step_precision, keep)
    finally:
        model.to("cpu")  # what fit's callers compute next (caches, fits, export) runs on the CPU


def _fit_on(model: ForceFusionNet, params: list, train: BatchSource, val: BatchSource, config: TrainConfig,
            device: torch.device, min_batch: int, checkpoint_path: str | Path | None, resume: bool, progress: bool,
            on_epoch_end: Callable[[int, dict], None] | None, desc: str, compared: dict[str, str] | None,
            data: dict | None, step_precision: str, keep: str) -> TrainResult:
    """`fit` on a model already on `device`."""
    # The fused implementation updates all parameters in one kernel: 2.4 ms less per head step than Adam's loop over
    # them; in the end-to-end phase it makes no difference in time (docs/learning.md), one optimiser serves both.
    optimizer = torch.optim.Adam(params, lr=config.learning_rate, fused=True)
    # Cosine annealing over the epoch budget (Loshchilov & Hutter 2017): the budget, not a plateau, ends
    # training here (the validation error of every phase still falls at its last epoch), and the small steps
    # of the last epochs settle the weights. It replaced halving on plateaus, which never triggered within
    # the end-to-end budget (docs/learning.md).
    scheduler = torch.optim.lr_scheduler.CosineAnnealingLR(optimizer, T_max=config.max_epochs,
                                                           eta_min=min(config.min_learning_rate,
                                                                       config.learning_rate))
    initial_val = normalised_rmse(model, val)
    state = {"epoch": 0, "initial_val": initial_val, "best_val": initial_val, "best_epoch": 0,
             "best_model": copy.deepcopy(model.state_dict()), "since_best": 0, "history": [], "wall_time_s": 0.0}
    checkpoint_path = Path(checkpoint_path) if checkpoint_path is not None else None
    if resume and checkpoint_path is not None and checkpoint_path.exists():
        state = _load_checkpoint(checkpoint_path, model, optimizer, scheduler, config, compared, data)

    epochs = tqdm(range(state["epoch"] + 1, config.max_epochs + 1), desc=desc, unit="epoch", disable=not progress,
                  initial=state["epoch"], total=config.max_epochs)
    for epoch in epochs:
        if state["since_best"] >= config.patience:
            break
        started = time.perf_counter()
        torch.manual_seed(config.seed * 100_003 + epoch)  # dropout masks of this epoch
        model.train()
        losses = []
        batches = epoch_batches(len(train), config.batch_size, config.seed, epoch, min_batch)
        for idx in tqdm(batches, desc=f"epoch {epoch}", unit="batch", leave=False, disable=not progress):
            with torch.autocast(device.type, dtype=torch.bfloat16, enabled=step_precision == "bf16"):
                prediction = train.predict(model, idx)
            loss = rmse_loss(prediction.float(), train.target(idx).to(device), config.loss_eps)
            optimizer.zero_grad(set_to_none=True)
            loss.backward()
            optimizer.step()
            losses.append(float(loss.detach()))
        val_rmse = normalised_rmse(model, val)
        scheduler.step()
        if val_rmse < state["best_val"]:
            state.update(best_val=val_rmse, best_epoch=epoch, best_model=copy.deepcopy(model.state_dict()),
                         since_best=0)
        else:
            state["since_best"] += 1
        record = {"epoch": epoch, "train_rmse": float(np.mean(losses)), "val_rmse": val_rmse,
                  "learning_rate": optimizer.param_groups[0]["lr"]}
        state["history"].append(record)
        state["epoch"] = epoch
        state["wall_time_s"] += time.perf_counter() - started
        epochs.set_postfix(val_rmse=f"{val_rmse:.4f}", best=f"{state['best_val']:.4f}")
        if checkpoint_path is not None:
            _save_checkpoint(checkpoint_path, model, optimizer, scheduler, config, state, data)
        if on_epoch_end is not None:
            on_epoch_end(epoch, record)
    epochs.close()
    if keep == "best":
        model.load_state_dict(state["best_model"])
    model.eval()
    return TrainResult(initial_val_rmse=state["initial_val"], best_epoch=state["best_epoch"],
                       best_val_rmse=state["best_val"], epochs_run=state["epoch"], wall_time_s=state["wall_time_s"],
                       stopped_early=state["epoch"] < config.max_epochs, history=state["history"],
                       step_precision=step_precision,
                       kept_epoch=state["best_epoch"] if keep == "best" else state["epoch"])


def train_phases(model: ForceFusionNet, train: FrameSet, val: FrameSet, config: TrainConfig,
                 checkpoint_dir: str | Path | None = None, resume: bool = False, progress: bool = False,
                 on_epoch_end: Callable[[int, dict], None] | None = None, head_extra: Iterable[FrameSet] = (),
                 fz_threshold: bool = False) -> dict:
    """End-to-end training; then (if config.head_epochs) the head alone on cached conv-trunk features; then the
    least-squares fit of the fusion layer; then, with `fz_threshold`, the Fz threshold and the fusion layer refitted
    for it (fz_threshold.fit_threshold_and_fusion; `tactile-fusion train` does this, the recalibration study compares
    its networks without).

    Why phases: an end-to-end step spends almost all its time in the convolutions at full resolution, while
    the head (fully connected layers and fusion) needs many more epochs than the conv filters to converge; with the
    trunk frozen its output is computed once and a head epoch costs a ninth to a sixteenth of an end-to-end one. And the
    fusion layer is linear: its exact least-squares weights for the final features beat what gradient steps
    reach (docs/learning.md). Each gradient phase keeps its own checkpoint in `checkpoint_dir`, so an
    interrupted run resumes in either phase (the least-squares fit is deterministic and takes seconds).

    With `config.head_cycles` > 1 the head phase and the fit run again, each further cycle from the fit before it,
    with a new cosine schedule and a newly drawn imperfect copy (seed + cycle - 1); its results get the suffix
    "_<cycle>". Measured after 13 end-to-end epochs (docs/learning_history.md): one, two, three and four cycles of 30
    epochs reached 3.25, 3.04, 2.90 and 2.82 mN per bin, 45 epochs in a row 3.15.

    The head phase keeps its last epoch and the cycle as a whole is judged after its fit: the model goes on with the
    cycle only if its validation RMSE, fitted, beats the model's before the cycle (the end-to-end result, or the
    fit of the last cycle kept); otherwise the weights from before the cycle are restored. Judging the head phase's
    epochs alone compared gradient-trained fusion layers against the exact fit that started the cycle: it held back
    a fifth cycle whose last epoch, fitted, was better (docs/learning.md).

    head_extra: more frames (in chunks; data.SceneDraws, further draws of the training scene) that the head phase and
    the fits learn from besides `train`, without an imperfect copy; the end-to-end phase does not see them. Measured
    from one end-to-end phase, five cycles: 2.30 mN per bin and 57 mN total Fz with 32340 frames of a further draw,
    2.47 / 64 without (docs/learning.md).

    With config.head_epochs 0 there is no head phase: nothing would learn from the imperfect copy, and every further
    cycle would repeat the same fit, so there is no copy and one cycle, whatever config.head_cycles says.

    Non-finite targets in `train` or `val` are refused first (data.FrameDataError).

    Returns {"end_to_end": TrainResult, "head": TrainResult (when it ran), "fusion_fit": least-squares report with
    "cycle_kept", and "head_2", "fusion_fit_2", ... for further cycles; with `fz_threshold` also "fz_threshold" and
    "fusion_refit"}.
    """
    check_finite_targets(training=train, validation=val)
    checkpoint_dir = Path(checkpoint_dir) if checkpoint_dir is not None else None
    scale = model.force_scale_n
    data = data_identity(train, val) if checkpoint_dir is not None else None  # only checkpoints record it
    with phase_dropout(model, config.end_to_end_dropout):
        results = {"end_to_end": fit(model, ImageSource(train, scale), ImageSource(val, scale), config,
                                     _phase_checkpoint(checkpoint_dir, "end_to_end"), resume, progress, on_epoch_end,
                                     desc="train end-to-end", compared=END_TO_END_COMPARED, data=data)}
    head = config.head_epochs > 0
    cached_train = CachedSource(model, train, "trunk", augmentation=config.head_augmentation() if head else None,
                                seed=config.seed, extra=head_extra)
    cached_val = CachedSource(model, val, "trunk")
    head_data = data  # a head checkpoint is resumed only on the same extra frames as well
    if data is not None and cached_train.extra_frames:
        head_data = data_identity(train, val, cached_train.targets[len(train):].numpy())
    kept_val_rmse, kept_ridge = results["end_to_end"].best_val_rmse, RIDGES[0]
    for cycle in range(1, (config.head_cycles if head else 1) + 1):
        suffix = "" if cycle == 1 else f"_{cycle}"
        if cycle > 1:
            cached_train.redraw_copy(model, train, config.head_augmentation(), config.seed + cycle - 1)
        before_cycle = copy.deepcopy(model.state_dict())
        if head:
            results[f"head{suffix}"] = _head_phase(model, cached_train, cached_val, config,
                                                   _phase_checkpoint(checkpoint_dir, f"head{suffix}"), resume,
                                                   progress, on_epoch_end, head_data)
        fitted = results[f"fusion_fit{suffix}"] = fit_fusion(model, cached_train.frames_only(), cached_val)
        fitted["cycle_kept"] = fitted["val_rmse_after"] < kept_val_rmse
        if fitted["cycle_kept"]:
            kept_val_rmse = fitted["val_rmse_after"]
            kept_ridge = fitted["ridge"] if fitted["ridge"] is not None else kept_ridge
        else:
            model.load_state_dict(before_cycle)
    model.eval()
    if fz_threshold:
        results.update(fit_threshold_and_fusion(model, cached_train.frames_only(), cached_val, kept_ridge))
    return results


def _head_phase(model: ForceFusionNet, cached_train: CachedSource, cached_val: CachedSource, config: TrainConfig,
                checkpoint_path: Path | None, resume: bool, progress: bool, on_epoch_end,
                data: dict | None) -> TrainResult:
    """The head alone on cached conv-trunk features, at the head phase's dropout, its last epoch kept (the cycle is
    judged after the fit, see train_phases); the model's trainable trunk is restored afterwards."""
    model.cnn.trunk.requires_grad_(False)
    try:
        with phase_dropout(model, config.head_dropout):
            phase = config.head_phase()
            return fit(model, cached_train, cached_val, phase, checkpoint_path, resume, progress, on_epoch_end,
                       desc="train head", compared=HEAD_COMPARED, data=data, step_precision=phase.head_precision,
                       keep="last")
    finally:
        model.cnn.trunk.requires_grad_(True)


@contextmanager
def phase_dropout(model: ForceFusionNet, rate: float | None) -> Iterator[None]:
    """The fully connected layers at `rate` (None: the model's own) for one phase (end to end: end_to_end_dropout;
    on cached features, the head phase and recalibration: head_dropout); the rate they had before restored
    afterwards, also on an exception."""
    model_dropout = model.cnn.set_dropout(model.config.dropout if rate is None else rate)
    try:
        yield
    finally:
        model.cnn.set_dropout(model_dropout)


#: Settings of a checkpoint written before they existed: dropout at the model's rate, no imperfect copy, one cycle,
#: float32 steps.
SETTINGS_BEFORE_THEY_EXISTED = {"end_to_end_dropout": None, "head_dropout": None, "head_noise_sigma": 0.0,
                                "head_blur_fraction": 0.0, "head_misalign_fraction": 0.0, "head_misalign_shift_px": 2.0,
                                "head_misalign_rotation_deg": 2.0, "head_cycles": 1, "head_precision": "fp32"}


def _model_rates(settings: dict, model: ForceFusionNet) -> dict:
    """`settings` with a dropout of None (the model's own rate) as that rate: a checkpoint written before
    --end-to-end-dropout existed trained at the model's 0.1, and is resumed by naming it (review: None, which it was
    compared with, cannot be given on the command line)."""
    return {**settings, **{k: model.config.dropout for k in ("end_to_end_dropout", "head_dropout")
                           if settings.get(k) is None}}


def data_identity(train: FrameSet, val: FrameSet, extra_targets: np.ndarray | None = None) -> dict:
    """What training runs on, as a checkpoint records it: the scene, its seed, the split sizes and a digest of the
    training and validation targets (which frames, in which order); for the head phase's checkpoints also the number
    and a digest of the targets of its extra frames (`extra_targets`, when it has any). Resuming on other frames
    (another scene, `--frames`, dataset, `--head-extra-draws`) would train one model on two data sets."""
    identity = {"scene": train.scene, "seed": int(train.seed), "train_frames": len(train), "val_frames": len(val),
                "targets_sha256": forces_sha256(train.bin_forces_n, val.bin_forces_n)}
    if extra_targets is not None:
        identity.update(head_extra_frames=len(extra_targets), head_extra_targets_sha256=forces_sha256(extra_targets))
    return identity


def _phase_checkpoint(checkpoint_dir: Path | None, phase: str) -> Path | None:
    return None if checkpoint_dir is None else checkpoint_dir / f"checkpoint_{phase}.pt"


def _save_checkpoint(path: Path, model: ForceFusionNet, optimizer, scheduler, config: TrainConfig, state: dict,
                     data: dict | None) -> None:
    # Whole or not at all: an interruption or a full disk never leaves a half-written checkpoint.
    write_torch_file(path, {"model": model.state_dict(), "model_config": model.config.to_dict(),
                            "components": list(model.components),
                            "optimizer": optimizer.state_dict(), "scheduler": scheduler.state_dict(),
                            "train_config": asdict(config), "data": data, "state": state},
                     "free disk space and resume (--resume)")


def _load_checkpoint(path: Path, model: ForceFusionNet, optimizer, scheduler, config: TrainConfig,
                     compared: dict[str, str] | None, data: dict | None) -> dict:
    try:
        checkpoint = torch.load(path, map_location="cpu", weights_only=False)
    except Exception as exc:  # the unpickler raises whatever a damaged file's bytes lead it to (found in review)
        raise CheckpointMismatchError(f"checkpoint {path} cannot be read ({type(exc).__name__}: {one_line(exc)}): it "
                                      "is damaged; delete it to train its phase afresh") from exc
    if not isinstance(checkpoint, dict):
        raise CheckpointMismatchError(f"checkpoint {path} holds a {type(checkpoint).__name__}, not a checkpoint of "
                                      "tactile-fusion train; delete it to train its phase afresh")
    # The model's shape is checked by load_state_dict, but not what it computes (the activation).
    if checkpoint.get("model_config") != model.config.to_dict():
        raise CheckpointMismatchError(f"checkpoint {path} was written for the model {checkpoint.get('model_config')}, "
                                      f"not {model.config.to_dict()}: resume with the same model settings or delete "
                                      "the checkpoint")
    malformed = _malformed_checkpoint(checkpoint)
    if malformed:
        raise CheckpointMismatchError(f"checkpoint {path} is not as tactile-fusion train writes one ({malformed}): it "
                                      "was edited or damaged; delete it to train its phase afresh")
    # Checkpoints written before models could leave components out estimated all three.
    with _as_malformed(path, "its components"):
        components = checked_components(checkpoint.get("components", FORCE_COMPONENTS))
    if components != model.components:
        raise CheckpointMismatchError(f"checkpoint {path} was written for a model estimating {list(components)}, but "
                                      f"this one estimates {list(model.components)} (the components its training "
                                      "data excites): delete the checkpoint to start afresh")
    # Settings added since the checkpoint was written count as what training did without them: their defaults, or
    # for the head phase's settings whose default changed, the value that reproduces the old behaviour.
    saved = checkpoint["train_config"]
    now = asdict(config)
    compared = compared if compared is not None else {k: k for k in now}
    if "head_noise_sigma" in compared and "head_blur_fraction" not in saved and saved.get("head_noise_sigma", 0.0) > 0:
        raise CheckpointMismatchError(f"checkpoint {path} was written when --head-noise-sigma replaced the training "
                                      "frames (it now adds an imperfect copy): delete the checkpoint")
    then = _model_rates({**asdict(TrainConfig()), **SETTINGS_BEFORE_THEY_EXISTED, **saved}, model)
    now = _model_rates(now, model)
    differences = [(name, then[k], now[k]) for k, name in compared.items() if then[k] != now[k]]
    if differences:
        raise SettingsMismatchError(path, differences)
    trained_on = checkpoint.get("data")
    if data is not None and trained_on is not None and trained_on != data:
        differ = ", ".join(f"{k} {trained_on.get(k)!r} (now {data.get(k)!r})" for k in {**trained_on, **data}
                           if trained_on.get(k) != data.get(k))
        raise CheckpointMismatchError(f"checkpoint {path} was trained on other data: {differ}; resume on the same "
                                      "scene or dataset and frames, or delete the checkpoints")
    # A phase that trains on top of frozen weights (the head on the conv trunk) must find the ones it was trained on:
    # a deleted and retrained end-to-end phase gives another trunk, and the checkpoint would put back the old one.
    changed = [name for name, p in model.named_parameters()
               if not p.requires_grad and name in checkpoint["model"]
               and not torch.equal(checkpoint["model"][name], p.detach().cpu())]
    if changed:
        raise CheckpointMismatchError(f"checkpoint {path} was trained on top of other frozen weights than this model "
                                      f"has ({changed[0]}, ...): the phase before it was trained again since; delete "
                                      "it to train its phase afresh")
    try:
        model.load_state_dict(checkpoint["model"])
    except RuntimeError as exc:
        raise CheckpointMismatchError(f"checkpoint {path} does not fit this model ({exc}); delete it to start "
                                      "afresh") from exc
    with _as_malformed(path, "its optimizer or scheduler state"):
        optimizer.load_state_dict(checkpoint["optimizer"])
        scheduler.load_state_dict(checkpoint["scheduler"])
    return checkpoint["state"]


#: The entries of a checkpoint that every version of `_save_checkpoint` wrote, and of its training state ("components"
#: and "data" came later; their absence has a meaning, see `_load_checkpoint`).
CHECKPOINT_ENTRIES = {"model": dict, "model_config": dict, "optimizer": dict, "scheduler": dict, "train_config": dict,
                      "state": dict}
STATE_ENTRIES = {"epoch": int, "initial_val": float, "best_val": float, "best_epoch": int, "best_model": dict,
                 "since_best": int, "history": list, "wall_time_s": float}


def _malformed_checkpoint(checkpoint: dict) -> str:
    """What makes a checkpoint unusable before anything is read from it (an entry missing or of the wrong kind, weights
    that are not tensors, best weights of another shape than its weights), or "" for none: a hand-edited or foreign
    one gave a KeyError traceback. Whether its weights fit the model is checked after its model settings, which say
    why they do not."""
    for entries, where in ((CHECKPOINT_ENTRIES, checkpoint), (STATE_ENTRIES, checkpoint.get("state", {}))):
        for name, kind in entries.items():
            value = where.get(name)
            if not isinstance(value, kind) or isinstance(value, bool):
                return f"{name} is {type(value).__name__ if name in where else 'missing'}, not {kind.__name__}"
    weights = (checkpoint["model"], checkpoint["state"]["best_model"])
    if not all(isinstance(t, torch.Tensor) for held in weights for t in held.values()):
        return "its weights are not all tensors"
    shapes = [{name: tuple(t.shape) for name, t in held.items()} for held in weights]
    return "its best weights are of another shape than its weights" if shapes[0] != shapes[1] else ""


@contextmanager
def _as_malformed(path: Path, what: str):
    """Entries that only their use can check, refused as CheckpointMismatchError naming `what`."""
    try:
        yield
    except (ValueError, KeyError, TypeError, IndexError) as exc:
        raise CheckpointMismatchError(f"checkpoint {path} is not as tactile-fusion train writes one ({what}: "
                                      f"{one_line(exc)}): it was edited or damaged; delete it to train its phase "
                                      "afresh") from exc
