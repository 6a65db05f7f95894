"""The paper's error measures (Trueeb et al. 2020, Table I) and their printed table.

- RMSE on the distribution, per component: sqrt(mean over frames and bins of (predicted - true)^2), for
  Fx, Fy, Fz separately (`rmse_bin_n`).
- RMSE on the total force, per component: the bin forces summed over the surface per frame, then the RMSE
  over frames (`rmse_total_n`).
"""

from __future__ import annotations

import numpy as np

COMPONENTS = ("Fx", "Fy", "Fz")


def force_metrics(predicted_n: np.ndarray, true_n: np.ndarray) -> dict:
    """Metrics of (N, rows, cols, 3) predictions against ground truth, all in newtons.

    Returns rmse_bin_n and rmse_total_n ([Fx, Fy, Fz] each), the largest true total Fz (max_total_fz_n), the
    total-Fz RMSE as a percentage of the data's total-Fz range (rmse_total_fz_percent_range) and the frame count.
    """
    predicted = np.asarray(predicted_n, dtype=np.float64)
    true = np.asarray(true_n, dtype=np.float64)
    if predicted.shape != true.shape or predicted.ndim != 4 or predicted.shape[-1] != 3:
        raise ValueError(f"force_metrics: predictions {predicted.shape} and ground truth {true.shape} must both be "
                         "(N, rows, cols, 3)")
    if predicted.shape[0] == 0:
        raise ValueError("force_metrics: no frames to evaluate")
    if not (np.isfinite(predicted).all() and np.isfinite(true).all()):
        raise ValueError("force_metrics: predictions or ground truth contain NaN or Inf")
    err = predicted - true
    rmse_bin = np.sqrt(np.mean(err**2, axis=(0, 1, 2)))
    total_err = err.sum(axis=(1, 2))
    rmse_total = np.sqrt(np.mean(total_err**2, axis=0))
    true_total_fz = true[..., 2].sum(axis=(1, 2))
    fz_range = float(true_total_fz.max() - min(0.0, float(true_total_fz.min())))
    return {
        "rmse_bin_n": [float(v) for v in rmse_bin],
        "rmse_total_n": [float(v) for v in rmse_total],
        "max_total_fz_n": float(true_total_fz.max()),
        "rmse_total_fz_percent_range": 100.0 * float(rmse_total[2]) / fz_range if fz_range > 0 else None,
        "frames": int(predicted.shape[0]),
    }


def metrics_table(rows: dict[str, dict]) -> str:
    """A fixed-width table: one line per evaluated data set (name -> force_metrics dict), values in mN."""
    head = (f"{'data set':<36}{'frames':>7}  " + "  ".join(f"bin {c} mN".rjust(11) for c in COMPONENTS) + "  "
            + "  ".join(f"total {c} mN".rjust(12) for c in COMPONENTS) + f"{'Fz % range':>12}")
    lines = [head, "-" * len(head)]
    for name, m in rows.items():
        percent = m.get("rmse_total_fz_percent_range")
        lines.append(f"{name:<36}{m['frames']:>7}  " + "  ".join(f"{1e3 * v:11.3f}" for v in m["rmse_bin_n"]) + "  "
                     + "  ".join(f"{1e3 * v:12.2f}" for v in m["rmse_total_n"])
                     + (f"{percent:12.2f}" if percent is not None else f"{'-':>12}"))
    return "\n".join(lines)
