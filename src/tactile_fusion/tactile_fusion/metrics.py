"""The paper's error measures (Trueeb et al. 2020, Table I) and their printed table.

- RMSE on the distribution, per component: sqrt(mean over frames and bins of (predicted - true)^2), for
  Fx, Fy, Fz separately (`rmse_bin_n`).
- RMSE on the total force, per component: the bin forces summed over the surface per frame, then the RMSE
  over frames (`rmse_total_n`).

Beyond the paper, what a robot feeling for contact asks of the sensor (`contact_metrics`): from which load on a
press is reported at all, whether a surface without load stays silent, and how far the estimated centre of pressure
lies from the true one.
"""

from __future__ import annotations

import numpy as np

from tactile_description.command_line import number_argument
from tactile_description.value_checks import is_number

COMPONENTS = ("Fx", "Fy", "Fz")
#: A frame's estimate reports a contact when its total Fz reaches this (newtons): about five times the error per bin.
CONTACT_LEVEL_N = 0.01
#: Loads (true total Fz, newtons) that contact detection is reported by: (0, 0.05], (0.05, 0.1], ... (0.5, inf).
LOAD_BAND_EDGES_N = (0.0, 0.05, 0.1, 0.2, 0.5, float("inf"))
#: The share of a band's frames that must be reported for the band to count as detected (`detected_from_n`) ...
DETECTED_SHARE = 0.9
#: ... and the frames a band needs for that judgement; a band with fewer is passed over.
MIN_BAND_FRAMES = 10


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


def _centre_of_pressure(fz_n: np.ndarray, bin_centers_m: np.ndarray) -> np.ndarray:
    """(N, 2) Fz-weighted mean (x, y) in metres of (N, rows, cols) Fz maps, over the bins pressed (Fz > 0: an
    estimate's negative bins are not a pull, which the gel cannot feel). NaN for a frame without any: private, for
    contact_metrics, which takes only frames that carry load."""
    pressed = np.clip(np.asarray(fz_n, dtype=np.float64), 0.0, None)
    load = pressed.sum(axis=(1, 2))
    weighted = np.einsum("nrc,rcd->nd", pressed, np.asarray(bin_centers_m, dtype=np.float64))
    with np.errstate(invalid="ignore", divide="ignore"):
        return weighted / load[:, None]


def contact_metrics(predicted_n: np.ndarray, true_n: np.ndarray, bin_centers_m: np.ndarray,
                    contact_level_n: float = CONTACT_LEVEL_N) -> dict:
    """Contact detection and localisation of (N, rows, cols, 3) predictions against the ground truth (newtons).

    A frame is reported as in contact when its estimated total Fz reaches `contact_level_n`. Returns
    contact_level_n; frames_without_load and false_contacts (those of them reported); bands, one per load band
    (`LOAD_BAND_EDGES_N`, on the true total Fz) with its frames, the share of them reported (reported_share, None
    for an empty band) and the distance between estimated and true centre of pressure over the frames reported,
    median and 95th percentile in mm (None where none was reported); detected_from_n (`detection_limit`).
    """
    contact_level_n = checked_contact_level(contact_level_n)
    predicted_fz = np.asarray(predicted_n, dtype=np.float64)[..., 2]
    true_fz = np.asarray(true_n, dtype=np.float64)[..., 2]
    if predicted_fz.shape != true_fz.shape or tuple(np.shape(bin_centers_m)) != true_fz.shape[1:] + (2,):
        raise ValueError(f"contact_metrics: predictions {np.shape(predicted_n)}, ground truth {np.shape(true_n)} and "
                         f"bin centres {np.shape(bin_centers_m)} do not match")
    if not (np.isfinite(predicted_fz).all() and np.isfinite(true_fz).all()):
        raise ValueError("contact_metrics: predictions or ground truth contain NaN or Inf")
    true_load = true_fz.sum(axis=(1, 2))
    reported = predicted_fz.sum(axis=(1, 2)) >= contact_level_n
    unloaded = true_load <= 0.0
    offset_mm = 1e3 * np.linalg.norm(_centre_of_pressure(predicted_fz, bin_centers_m)
                                     - _centre_of_pressure(true_fz, bin_centers_m), axis=1)
    bands = []
    for low, high in zip(LOAD_BAND_EDGES_N[:-1], LOAD_BAND_EDGES_N[1:], strict=True):
        in_band = (true_load > low) & (true_load <= high)
        located = offset_mm[in_band & reported]
        bands.append({"load_n": [low, high if np.isfinite(high) else None], "frames": int(in_band.sum()),
                      "reported_share": float(reported[in_band].mean()) if in_band.any() else None,
                      "centre_error_mm_median": float(np.median(located)) if located.size else None,
                      "centre_error_mm_p95": float(np.percentile(located, 95)) if located.size else None})
    return {"contact_level_n": contact_level_n, "frames_without_load": int(unloaded.sum()),
            "false_contacts": int((reported & unloaded).sum()), "bands": bands,
            "detected_from_n": detection_limit(bands)}


def detection_limit(bands: list[dict]) -> float | None:
    """The load from which presses are reported: the lower edge of the lightest of the heaviest bands that are all
    reported in at least `DETECTED_SHARE` of their frames, judged on bands of at least `MIN_BAND_FRAMES` frames.

    Only where the data show it: a lighter judged band that falls short, or the lightest band of all passing (then
    0, any load). Data without light presses (every judged band passes, the lightest judged one above 0) give None,
    as does data whose heaviest judged band falls short.
    """
    judged = [b for b in bands if b["frames"] >= MIN_BAND_FRAMES]
    limit = None
    for band in reversed(judged):
        if band["reported_share"] < DETECTED_SHARE:
            return limit
        limit = band["load_n"][0]
    return limit if limit == 0.0 else None


def checked_contact_level(contact_level_n) -> float:
    """The contact level as a float, a finite number > 0 (newtons); ValueError otherwise."""
    if not (is_number(contact_level_n) and contact_level_n > 0):
        raise ValueError(f"contact_metrics: contact_level_n must be a finite number > 0 (newtons), got "
                         f"{contact_level_n!r}")
    return float(contact_level_n)


#: `--contact-level NEWTONS` of `tactile-fusion eval` and `tactile-bag eval` (an argparse type), refused before any
#: evaluation runs.
contact_level_argument = number_argument(0.0, "newtons")


def contact_table(rows: dict[str, dict]) -> str:
    """A fixed-width table of `contact_metrics` per data set: false contacts, then per load band the share of
    frames reported (%) and the median error of the centre of pressure (mm)."""
    first = next(iter(rows.values()))
    bands = [b["load_n"] for b in first["bands"]]
    names = [f"{lo:g}-{hi:g} N" if hi is not None else f"> {lo:g} N" for lo, hi in bands]
    head = f"{'data set':<36}{'false contacts':>16}" + "".join(f"{n:>16}" for n in names) + f"{'detected from':>15}"
    lines = [f"contact: estimated total Fz >= {1e3 * first['contact_level_n']:g} mN; per load band: % of its frames "
             "reported, median error of the centre of pressure", head, "-" * len(head)]
    for name, m in rows.items():
        cells = []
        for band in m["bands"]:
            if band["reported_share"] is None:
                cells.append("-")
            else:
                median = band["centre_error_mm_median"]
                cells.append(f"{100 * band['reported_share']:.0f} %"
                             + (f" {median:.2f} mm" if median is not None else ""))
        false = f"{m['false_contacts']} of {m['frames_without_load']}"
        detected_from = f"{m['detected_from_n']:g} N" if m["detected_from_n"] is not None else "-"
        lines.append(f"{name:<36}{false:>16}" + "".join(f"{c:>16}" for c in cells) + f"{detected_from:>15}")
    return "\n".join(lines)
