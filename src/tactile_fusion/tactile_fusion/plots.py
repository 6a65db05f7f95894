"""Figures for people: ground truth vs predicted Fz maps (like the paper's Fig. 5) and the recalibration sweep."""

from __future__ import annotations

import io
from pathlib import Path

import matplotlib

matplotlib.use("Agg")  # files only, no display needed
import matplotlib.pyplot as plt
import numpy as np

from tactile_description import BinGrid
from tactile_fusion.artifacts import replace_file, unwritable


def save_png(fig, path: str | Path) -> Path:
    """Write `fig` as a PNG to `path` whole or not at all (artifacts.replace_file) and close it; ModelFileError naming
    the file if it cannot be written (a directory in its place, a full disk), as for the JSON beside it."""
    path = Path(path)
    png = io.BytesIO()
    try:
        fig.savefig(png, format="png", dpi=110)
    finally:
        plt.close(fig)
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        replace_file(path, png.getvalue())
    except OSError as exc:
        raise unwritable(path, exc, "run the command again") from exc
    return path


def example_frames(true_n: np.ndarray, count: int = 3) -> list[int]:
    """Frames worth showing: the largest total Fz, then the frames at 30 %, 60 %, ... of the ranking."""
    order = np.argsort(-true_n[..., 2].sum(axis=(1, 2)))
    picks = [int(order[round(0.3 * i * (len(order) - 1))]) for i in range(count) if 0.3 * i <= 1.0]
    return list(dict.fromkeys(picks))


def plot_fz_maps(true_n: np.ndarray, predicted_n: np.ndarray, path: str | Path, title: str,
                 frames: list[int] | None = None, bin_size_mm: tuple[float, float] | None = None) -> Path:
    """Ground truth (top row) and predicted (bottom row) Fz maps in newtons for a few frames, shared colour scale.

    bin_size_mm: (along x, along y) of a bin of the sensor's grid (`grid_bin_size_mm`), for axes in millimetres; None:
    axes in bins."""
    frames = frames if frames is not None else example_frames(true_n)
    fig, axes = plt.subplots(2, len(frames), figsize=(3.4 * len(frames) + 0.8, 6.4), squeeze=False,
                             constrained_layout=True)
    vmax = max(float(true_n[frames][..., 2].max()), float(predicted_n[frames][..., 2].max()), 1e-6)
    rows, cols = true_n.shape[1:3]
    width, length = (1.0, 1.0) if bin_size_mm is None else bin_size_mm
    extent = (0, cols * width, rows * length, 0)
    unit = "bins" if bin_size_mm is None else "mm"
    image = None
    for j, frame in enumerate(frames):
        for i, (label, data) in enumerate((("ground truth", true_n), ("prediction", predicted_n))):
            ax = axes[i, j]
            image = ax.imshow(data[frame, :, :, 2], cmap="viridis", vmin=0.0, vmax=vmax, extent=extent)
            total = float(data[frame, :, :, 2].sum())
            ax.set_title(f"frame {frame}: {label}\ntotal Fz {total:.3f} N", fontsize=9)
            ax.set_xlabel(f"x ({unit})", fontsize=8)
            ax.set_ylabel(f"y ({unit})", fontsize=8)
            ax.tick_params(labelsize=7)
    fig.colorbar(image, ax=axes, label="bin Fz (N)", shrink=0.8)
    fig.suptitle(title)
    return save_png(fig, path)


def grid_bin_size_mm(grid: BinGrid) -> tuple[float, float]:
    """(along x, along y) of a bin of `grid` in millimetres, as plot_fz_maps takes it."""
    return 1e3 * grid.bin_width_m, 1e3 * grid.bin_length_m


def trend_line_mn(trend: dict, fractions: np.ndarray, scale: float = 1.0) -> tuple[np.ndarray, np.ndarray]:
    """(data fraction in %, error in mN times `scale`) along a trend line of the recalibration study (newtons per unit
    fraction: `slope_n_per_fraction`, `intercept_n`) over the range of `fractions`."""
    line = np.linspace(fractions.min(), fractions.max(), 50)
    return 100 * line, (trend["slope_n_per_fraction"] * line + trend["intercept_n"]) * scale * 1e3


def plot_recalibration(sweep: dict, path: str | Path) -> Path:
    """Left: test errors against the fraction of data used for recalibration, with the study's least-squares trend
    lines and the fully trained model's error; right: wall time of full training against recalibration, titled with
    the study's speed-up (`sweep`: the report study.run_recalibration_study writes)."""
    fractions = np.array([run["fraction"] for run in sweep["recalibration"]])
    fig, (ax, bx) = plt.subplots(1, 2, figsize=(11, 5), constrained_layout=True)
    for key, label, colour in (("rmse_bin_n", "per-bin Fz RMSE", "tab:blue"),
                               ("rmse_total_n", "total Fz RMSE / 10", "tab:orange")):
        scale = 0.1 if key == "rmse_total_n" else 1.0
        errors = np.array([run["metrics"][key][2] for run in sweep["recalibration"]]) * scale * 1e3
        ax.plot(fractions * 100, errors, "o", color=colour, label=f"recalibrated: {label}")
        percent, line_mn = trend_line_mn(sweep["trend_lines"][f"{key}_fz"], fractions, scale)
        ax.plot(percent, line_mn, "-", color=colour, alpha=0.6,
                label=f"trend {line_mn[-1] - line_mn[0]:+.3f} mN over {percent[-1] - percent[0]:.0f} % data")
        ax.axhline(sweep["full_training"]["metrics"][key][2] * scale * 1e3, color=colour, ls="--", alpha=0.7,
                   label=f"full training, all cameras ({label})")
        if "base_training" in sweep:
            ax.axhline(sweep["base_training"]["metrics"][key][2] * scale * 1e3, color=colour, ls=":", alpha=0.7,
                       label=f"before recalibration, {sweep['base_cameras']} cameras ({label})")
    ax.set_xlabel("training data used for recalibration (%)")
    ax.set_ylabel("RMSE on the test split (mN)")
    ax.set_title(f"adding camera {sweep['added_camera']} to a {sweep['base_cameras']}-camera model")
    # Below the axes: inside, the legend hid some of the points wherever it was put.
    ax.legend(fontsize=6, loc="upper center", bbox_to_anchor=(0.5, -0.16), ncols=2)
    names = ["full training"] + [f"recal. {100 * f:.0f} %" for f in fractions]
    times = [sweep["full_training"]["wall_time_s"]] + [run["wall_time_s"] for run in sweep["recalibration"]]
    bx.bar(range(len(names)), times, color=["tab:red"] + ["tab:green"] * len(fractions))
    bx.set_xticks(range(len(names)), names, rotation=60, ha="right", fontsize=7)
    bx.set_ylabel("wall time (s)")
    speedup = sweep["speedup"]
    bx.set_title(f"full training / recalibration ({100 * speedup['fraction']:.0f} % data): {speedup['factor']:.1f}x")
    return save_png(fig, path)
