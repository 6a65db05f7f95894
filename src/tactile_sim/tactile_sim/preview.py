"""PNG previews of simulated frames for people: each camera's view, its difference to the rest frame, and the
ground-truth force map. Camera panels are laid out as the cameras sit under the surface (seen from below, the
way the images come out: x to the right, y downwards), and so is the force map.
"""

from __future__ import annotations

import os
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np
from matplotlib.patches import Circle

from tactile_description import SensorDescription
from tactile_sim.scene import Scene
from tactile_sim.simulator import Frame

#: Difference images are shown on a fixed scale of +- this many grey levels, so previews compare at a glance.
DIFFERENCE_RANGE = 40


def camera_layout(sensor: SensorDescription) -> tuple[int, int, list[tuple[int, int]]]:
    """(rows, cols, [(row, col) per camera]): the cameras' grid under the surface, by their x and y positions."""
    xs = sorted({round(c.position_m[0], 4) for c in sensor.cameras})
    ys = sorted({round(c.position_m[1], 4) for c in sensor.cameras})
    cells = [(ys.index(round(c.position_m[1], 4)), xs.index(round(c.position_m[0], 4))) for c in sensor.cameras]
    if len(set(cells)) != len(cells):  # not a grid: one row
        return 1, sensor.n_cameras, [(0, i) for i in range(sensor.n_cameras)]
    return len(ys), len(xs), cells


def preview_figure(frame: Frame, reference: np.ndarray, sensor: SensorDescription, title: str = ""):
    """A matplotlib Figure: camera views | differences to the rest frames | Fz map with the tangential forces."""
    rows, cols, cells = camera_layout(sensor)
    panel = 2.0
    force_width = 1.6 * max(1.0, rows / 2)
    fig = plt.figure(figsize=((2 * cols + 0.5 + force_width) * panel, rows * panel + 0.9), dpi=110)
    grid = fig.add_gridspec(rows, 2 * cols + 3, width_ratios=[1] * (2 * cols) + [0.06, 0.5, force_width],
                            wspace=0.08, hspace=0.15)
    difference = frame.images.astype(np.int16) - reference.astype(np.int16)  # int16: no uint8 wrap-around
    shown = None
    for i, (r, c) in enumerate(cells):
        cam_id = sensor.camera_ids[i]
        status = "" if frame.camera_ok[i] else "  DROPPED"
        ax = fig.add_subplot(grid[r, c])
        ax.imshow(frame.images[i], cmap="gray", vmin=0, vmax=255, interpolation="nearest")
        ax.set_title(f"{cam_id}{status}", fontsize=8, color="red" if status else "black")
        ax.axis("off")
        ax = fig.add_subplot(grid[r, cols + c])
        shown = ax.imshow(difference[i], cmap="seismic", vmin=-DIFFERENCE_RANGE, vmax=DIFFERENCE_RANGE,
                          interpolation="nearest")
        ax.set_title(f"{cam_id} - rest", fontsize=8)
        ax.axis("off")
    cax = fig.add_subplot(grid[:, 2 * cols])
    fig.colorbar(shown, cax=cax).set_label("difference to the rest frame (grey levels)", fontsize=8)
    cax.tick_params(labelsize=7)
    _force_panel(fig.add_subplot(grid[:, 2 * cols + 2]), frame, sensor)
    total = frame.bin_forces_n.reshape(-1, 3).sum(axis=0)
    fig.suptitle(f"{title}  frame {frame.index}  t = {frame.time_s:.3f} s  total F = ({total[0]:+.3f}, "
                 f"{total[1]:+.3f}, {total[2]:+.3f}) N", fontsize=9)
    return fig


def _force_panel(ax, frame: Frame, sensor: SensorDescription) -> None:
    grid = sensor.grid
    extent_mm = (0, grid.width_m * 1e3, grid.length_m * 1e3, 0)
    fz = frame.bin_forces_n[..., 2]
    top = max(float(np.abs(fz).max()), 1e-3)
    image = ax.imshow(fz, cmap="inferno", vmin=0, vmax=top, extent=extent_mm, interpolation="nearest")
    centres = grid.bin_centers_m() * 1e3
    fxy = frame.bin_forces_n[..., :2]
    strength = np.hypot(fxy[..., 0], fxy[..., 1])
    if strength.max() > 1e-6:
        big = strength > 0.02 * strength.max()
        ax.quiver(centres[..., 0][big], centres[..., 1][big], fxy[..., 0][big], fxy[..., 1][big], color="cyan",
                  angles="xy", scale_units="xy", scale=strength.max() / 4.0, width=0.006)
    for contact in frame.contacts:
        radius = getattr(contact.shape, "radius_m", 0.0)
        ax.add_patch(Circle((contact.x_m * 1e3, contact.y_m * 1e3), max(radius, 0.5e-3) * 1e3, fill=False,
                            color="white", linestyle="--", linewidth=0.8))
    ax.set_xlim(0, grid.width_m * 1e3)
    ax.set_ylim(grid.length_m * 1e3, 0)
    ax.set_xlabel("x (mm)", fontsize=8)
    ax.set_ylabel("y (mm)", fontsize=8)
    ax.tick_params(labelsize=7)
    ax.set_title("ground truth: Fz per bin (N), arrows Fx, Fy;\n dashed: indenter outline", fontsize=8)
    plt.colorbar(image, ax=ax, fraction=0.046, pad=0.03).ax.tick_params(labelsize=7)


def save_preview(path: str | os.PathLike, frame: Frame, reference: np.ndarray, sensor: SensorDescription,
                 title: str = "") -> Path:
    fig = preview_figure(frame, reference, sensor, title)
    try:  # a figure that cannot be saved (disk full) is closed all the same: pyplot keeps every open one
        fig.savefig(path, bbox_inches="tight")
    finally:
        plt.close(fig)
    return Path(path)


def preview_indices(n_frames: int, count: int) -> list[int]:
    """`count` frame indices spread evenly over a scene of `n_frames` (first and last included)."""
    if n_frames < 1 or count < 1:
        return []
    return sorted({int(round(i)) for i in np.linspace(0, n_frames - 1, min(count, n_frames))})


def write_previews(sim, scene: Scene, out_dir: str | os.PathLike, count: int = 8,
                   frames: int | None = None) -> list[Path]:
    """Stream the scene and save previews of `count` evenly spread frames, plus rest.png (the rest frames)."""
    if frames is not None:
        scene = scene.limited(frames)
    stream = sim.stream(scene)  # checks the scene before the directory is made, as write_dataset
    directory = Path(out_dir)
    directory.mkdir(parents=True, exist_ok=True)
    reference = sim.reference_images()
    wanted = set(preview_indices(len(scene), count))
    written = [_save_rest(directory / "rest.png", reference, sim.sensor)]
    for frame in stream:
        if frame.index in wanted:
            written.append(save_preview(directory / f"{scene.name}_{frame.index:06d}.png", frame, reference,
                                        sim.sensor, title=scene.name))
        if frame.index >= max(wanted, default=-1):
            break
    return written


def _save_rest(path: Path, reference: np.ndarray, sensor: SensorDescription) -> Path:
    rows, cols, cells = camera_layout(sensor)
    fig, axes = plt.subplots(rows, cols, figsize=(cols * 2.6, rows * 2.6 + 0.4), dpi=110, squeeze=False)
    for i, (r, c) in enumerate(cells):
        axes[r, c].imshow(reference[i], cmap="gray", vmin=0, vmax=255, interpolation="nearest")
        axes[r, c].set_title(sensor.camera_ids[i], fontsize=8)
    for ax in axes.ravel():
        ax.axis("off")
    fig.suptitle(f"{sensor.name}: rest frames (the reference the model subtracts)", fontsize=9)
    try:
        fig.savefig(path, bbox_inches="tight")
    finally:
        plt.close(fig)
    return path
