"""Offline evaluation of a bag, without DDS: what the fusion node would have estimated from the recorded images,
compared with the simulator's ground truth recorded beside them.

1. Bundles: the camera images are bundled by capture stamp with the live graph's synchroniser
   (tactile_fusion.approximate_sync, with bundle_node's default settings), or the recorded ImageBundles are
   taken as they are (a bag without every camera's images, or `source="bundles"`).
2.-3. The bundles go through fusion_node's own loop (tactile_fusion.live_estimation.LiveEstimation):
   reference frames, the pixel-wise mean of the first `reference_bundles` complete bundles (every camera present
   and readable), or, when `REFERENCE_PATIENCE_BUNDLES` bundles bring fewer complete ones, of the last
   `reference_bundles` of them over the cameras usable in each (the others left out: live_estimation.ReferenceFrames),
   rounded to uint8, the bundles until then not estimated; a malformed bundle (not one image per camera id) or one of
   another sensor (a camera the sensor description does not name) is skipped; then every later bundle through the
   predictor, a missing or unreadable camera shown at rest (tactile_fusion.camera_out; it reports "no contact") and
   the estimate counted as degraded, and whether each
   camera's images still match its reference frame checked (live_estimation.ReferenceMatch).
4. Each estimate is matched with the ground-truth message nearest to its bundle stamp, if one lies within
   `match_tolerance_s` (the bundle stamp is the median of the cameras' capture stamps, the truth is stamped
   with the capture time), and the paper's metrics are computed over the matched pairs
   (tactile_fusion.metrics.force_metrics: RMSE per component per bin and of the total force).
"""

from __future__ import annotations

import functools
import statistics
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
from rclpy.serialization import deserialize_message
from sensor_msgs.msg import Image

from tactile_bag.bagfile import BagError, BagReader, DefinitionMismatchError
from tactile_bag.topics import BUNDLE_TYPE, FORCES_TYPE, IMAGE_TYPE, camera_topics
from tactile_conversions.forces import forces_from_msg
from tactile_conversions.images import bundle_problem, frame_from_images
from tactile_conversions.ros_time import is_ros_stamp, is_ros_time, time_to_seconds
from tactile_conversions.topics import (
    BUNDLE_TOPIC,
    GROUND_TRUTH_TOPIC,
    MATCH_TOLERANCE_S,
    ROOT_NAMESPACE,
    graph_namespace,
    in_namespace,
)
from tactile_description import SensorDescription
from tactile_fusion.approximate_sync import ApproximateTimeSync, camera_sync_settings
from tactile_fusion.live_estimation import REFERENCE_BUNDLES, BundleSequence, LiveEstimation
from tactile_fusion.metrics import CONTACT_LEVEL_N, contact_metrics, force_metrics
from tactile_msgs.msg import ForceDistribution, ImageBundle

if TYPE_CHECKING:  # the model stack (torch, onnxruntime) takes seconds to import: only the caller loads it
    from tactile_fusion.inference import ForcePredictor

SOURCES = ("auto", "images", "bundles")


@dataclass
class BundleFrame:
    """One bundle as the model sees it: images (C, H, W) uint8 in the sensor's camera order."""

    stamp_s: float
    images: np.ndarray
    camera_ok: np.ndarray  # (C,) bool: False for a camera missing from the bundle or with an unreadable image
    unusable: bool = False  # malformed or of another sensor (images.bundle_problem): skipped, not estimated


@dataclass
class BagEvaluation:
    """Estimates of one bag and their ground truth; `summary()` is what `tactile-bag eval --json` prints."""

    bag: str
    source: str
    camera_ids: tuple[str, ...]
    bundles: int
    reference_bundles: int
    stamps_s: np.ndarray            # (N,) bundle stamps of the estimates
    estimates_n: np.ndarray         # (N, rows, cols, 3) float32
    camera_ok: np.ndarray           # (N, C) bool
    off_reference: np.ndarray | None  # (N, C) bool: the camera no longer matched its reference frame (ReferenceMatch);
    #                                   None: not checked (a reference of one bundle)
    reference_cameras: np.ndarray   # (C,) bool: the cameras the reference frames were taken with (ReferenceFrames)
    truth_messages: int
    truth_index: np.ndarray         # (N,) index into truth_n of the matched ground truth, -1 for none
    truth_n: np.ndarray             # (M, rows, cols, 3) float32, every ground truth message of the bag
    bin_centers_m: np.ndarray       # (rows, cols, 2) of the sensor's bins, for the centre of pressure
    skipped: dict[str, int] = field(default_factory=dict)  # why images or bundles were not used, with counts
    contact_level_n: float = CONTACT_LEVEL_N  # estimated total Fz from which an estimate reports contact
    other_image_topics: tuple[str, ...] = ()  # image topics of the bag that no camera of the description publishes

    @property
    def matched(self) -> np.ndarray:
        return self.truth_index >= 0

    @functools.cached_property
    def metrics(self) -> dict | None:
        """force_metrics over the estimates that have ground truth, with their contact_metrics under "contact", or
        None without any (computed once: summary() and the CLI's tables both read it)."""
        if not self.matched.any():
            return None
        estimates, truth = self.estimates_n[self.matched], self.truth_n[self.truth_index[self.matched]]
        return force_metrics(estimates, truth) | {"contact": contact_metrics(estimates, truth, self.bin_centers_m,
                                                                             self.contact_level_n)}

    def summary(self) -> dict:
        totals = self.estimates_n.astype(np.float64).sum(axis=(1, 2))
        metrics = self.metrics or {}
        missing = sorted({c for row in self.camera_ok for c, ok in zip(self.camera_ids, row, strict=True) if not ok})
        off = self.off_reference if self.off_reference is not None else np.zeros_like(self.camera_ok)
        return {
            "bag": self.bag,
            "source": self.source,
            "bundles": self.bundles,
            "reference_bundles": self.reference_bundles,
            "estimates": len(self.stamps_s),
            "degraded_estimates": int((~self.camera_ok).any(axis=1).sum()),
            "missing_camera_ids": missing,
            "cameras_without_reference": [c for c, ok in zip(self.camera_ids, self.reference_cameras, strict=True)
                                          if not ok],
            "reference_checked": self.off_reference is not None,
            "estimates_off_reference": int(off.any(axis=1).sum()),
            "off_reference_camera_ids": [c for c, o in zip(self.camera_ids, off.any(axis=0), strict=True) if o],
            "skipped": dict(self.skipped),
            "other_image_topics": list(self.other_image_topics),
            "ground_truth_messages": self.truth_messages,
            "matched_with_ground_truth": int(self.matched.sum()),
            "rmse_bin_n": metrics.get("rmse_bin_n"),
            "rmse_total_n": metrics.get("rmse_total_n"),
            "rmse_total_fz_percent_range": metrics.get("rmse_total_fz_percent_range"),
            "max_true_total_fz_n": metrics.get("max_total_fz_n"),
            "contact": metrics.get("contact"),
            "estimated_total_n": {"mean": totals.mean(axis=0).tolist(), "min": totals.min(axis=0).tolist(),
                                  "max": totals.max(axis=0).tolist()} if len(totals) else None,
        }


def deserialize(raw: bytes, cls: type, topic: str, time_ns: int):
    try:
        return deserialize_message(raw, cls)
    except RuntimeError as exc:  # rclpy's RMWError: the bytes are not a CDR message of this type
        raise BagError(f"message on {topic} received at {time_ns} ns cannot be read as {cls.__name__}: the bag is "
                       "damaged or the topic's recorded type is wrong") from exc


def choose_source(bag: BagReader, sensor: SensorDescription, source: str = "auto",
                  namespace: str = ROOT_NAMESPACE) -> str:
    """'images' when the bag has every camera's images (or asked), 'bundles' for recorded ImageBundles, of the graph
    in `namespace`."""
    if source not in SOURCES:
        raise ValueError(f"source must be one of {SOURCES}, got {source!r}")
    image_topics = list(camera_topics(sensor, namespace))
    bundle_topic = in_namespace(BUNDLE_TOPIC, namespace)
    for topic in [*image_topics, bundle_topic]:
        expected = BUNDLE_TYPE if topic == bundle_topic else IMAGE_TYPE
        if topic in bag.topics and bag.topics[topic] != expected:
            raise BagError(f"bag {bag.path}: {topic} holds {bag.topics[topic]}, expected {expected}")
    without_images = [t for t in image_topics if not bag.counts.get(t)]
    has_bundles = bool(bag.counts.get(bundle_topic))
    if source == "images" and without_images or source == "auto" and without_images and not has_bundles:
        raise BagError(f"bag {bag.path} has no camera images on {without_images}"
                       + ("" if has_bundles else f" and no image bundles on {bundle_topic}")
                       + f": record them (the sensor description {sensor.source or sensor.name} names cameras "
                       f"{list(sensor.camera_ids)})" + _namespaces_hint(bag, namespace))
    if source == "bundles" and not has_bundles:
        raise BagError(f"bag {bag.path} has no image bundles on {bundle_topic}: evaluate its camera images instead "
                       "(--source images) or record the bundle node's output" + _namespaces_hint(bag, namespace))
    if source == "auto":
        return "bundles" if without_images else "images"
    return source


def _namespaces_hint(bag: BagReader, namespace: str) -> str:
    """"; ..." naming the namespaces other than `namespace` whose graphs the bag holds (found by their bundle or
    ground-truth topics), "" for none."""
    found = sorted({topic.removesuffix(suffix) or ROOT_NAMESPACE for topic in bag.topics
                    for suffix in (BUNDLE_TOPIC, GROUND_TRUTH_TOPIC) if topic.endswith(suffix)}
                   - {graph_namespace(namespace)})
    return f"; the bag holds the topics of graphs in the namespaces {found} (--namespace)" if found else ""


class FrameReader:
    """Image messages -> (C, H, W) uint8 frames in the sensor's camera order, counting what was unusable."""

    def __init__(self, sensor: SensorDescription, image_size: int):
        self.camera_ids = sensor.camera_ids
        self.shape = (image_size, image_size)
        self.skipped: dict[str, int] = {}

    def skip(self, reason: str) -> None:
        self.skipped[reason] = self.skipped.get(reason, 0) + 1

    def frame(self, stamp_s: float, camera_ids, images: list[Image]) -> BundleFrame:
        frame, camera_ok, problems = frame_from_images(camera_ids, images, self.camera_ids, self.shape)
        for reason, _ in problems:
            self.skip(reason)
        return BundleFrame(stamp_s, frame, camera_ok, bundle_problem(camera_ids, images, self.camera_ids) is not None)


def image_bundles(bag: BagReader, sensor: SensorDescription, reader: FrameReader,
                  namespace: str = ROOT_NAMESPACE) -> Iterator[BundleFrame]:
    """The camera images (of the graph in `namespace`) bundled as bundle_node bundles them (same synchroniser, same
    default settings, images whose stamp no bundle can carry dropped)."""
    sync: ApproximateTimeSync[Image] = ApproximateTimeSync(sensor.camera_ids,
                                                           **camera_sync_settings(sensor.frame_rate_hz))
    cameras = camera_topics(sensor, namespace)
    for topic, _, time_ns, raw in bag.messages(list(cameras)):
        msg = deserialize(raw, Image, topic, time_ns)
        stamp_s = time_to_seconds(msg.header.stamp)
        if not is_ros_time(stamp_s):
            sync.dropped.drop_bad_stamp(cameras[topic])
            continue
        for bundle in sync.add(cameras[topic], stamp_s, msg):
            yield reader.frame(statistics.median(bundle.stamps), bundle.stream_ids, list(bundle.items))
    for reason, count in sync.dropped.by_reason().items():
        if count:
            reader.skipped[f"images dropped by the synchroniser ({reason})"] = count


def recorded_bundles(bag: BagReader, reader: FrameReader, namespace: str = ROOT_NAMESPACE) -> Iterator[BundleFrame]:
    """The recorded ImageBundles (of the graph in `namespace`); the ones the recorder never got (gaps in their
    numbers) are counted as skipped, and so are bundles stamped before 1970 (or at 2**31 s and later), which
    fusion_node skips too."""
    sequence = BundleSequence()
    for topic, _, time_ns, raw in bag.messages([in_namespace(BUNDLE_TOPIC, namespace)]):
        msg = deserialize(raw, ImageBundle, topic, time_ns)
        sequence.add(msg.sequence)
        if not is_ros_stamp(msg.header.stamp):  # as fusion_node skips it: no estimate can carry its stamp
            reader.skip("bundle stamped outside [0, 2**31) s")
            continue
        yield reader.frame(time_to_seconds(msg.header.stamp), list(msg.camera_ids), list(msg.images))
    if sequence.lost:
        reader.skipped["bundles missing from the recording (gaps in their sequence numbers)"] = sequence.lost


def read_ground_truth(bag: BagReader, sensor: SensorDescription, topic: str = GROUND_TRUTH_TOPIC,
                      required: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """Stamps (M,) in seconds and forces (M, rows, cols, 3) of the bag's ground truth.

    A bag without the topic has no ground truth (empty arrays), or is an error when it is `required`.
    """
    if topic not in bag.topics and not required:
        return no_ground_truth(sensor)
    bag.require_topics([topic])
    if bag.topics[topic] != FORCES_TYPE:
        raise BagError(f"bag {bag.path}: {topic} holds {bag.topics[topic]}, expected {FORCES_TYPE}")
    stamps, forces = [], []
    for _, _, time_ns, raw in bag.messages([topic]):
        msg = deserialize(raw, ForceDistribution, topic, time_ns)
        try:
            values = forces_from_msg(msg, sensor.grid).astype(np.float32)
        except ValueError as exc:
            raise BagError(f"bag {bag.path}: ground truth on {topic} at {time_ns} ns has {exc}: evaluate with the "
                           "sensor description the bag was recorded with (--sensor), or record the ground truth "
                           "again") from exc
        stamps.append(time_to_seconds(msg.header.stamp))
        forces.append(values)
    if not forces:
        return no_ground_truth(sensor)
    return np.asarray(stamps), np.stack(forces)


def no_ground_truth(sensor: SensorDescription) -> tuple[np.ndarray, np.ndarray]:
    """The stamps and forces of a bag without ground truth, as read_ground_truth returns them."""
    return np.zeros(0), np.zeros((0, sensor.grid.rows, sensor.grid.cols, 3), np.float32)


def match_stamps(stamps_s: np.ndarray, truth_stamps_s: np.ndarray, tolerance_s: float = MATCH_TOLERANCE_S
                 ) -> np.ndarray:
    """For each stamp, the index of the nearest truth stamp within `tolerance_s` (inclusive), else -1."""
    stamps_s = np.asarray(stamps_s, dtype=np.float64)
    if not len(truth_stamps_s):
        return np.full(len(stamps_s), -1)
    order = np.argsort(truth_stamps_s, kind="stable")
    sorted_truth = np.asarray(truth_stamps_s, dtype=np.float64)[order]
    after = np.searchsorted(sorted_truth, stamps_s)  # first truth at or after each stamp, len(truth) if none
    left = np.clip(after - 1, 0, len(sorted_truth) - 1)
    right = np.clip(after, 0, len(sorted_truth) - 1)
    nearest = np.where(np.abs(sorted_truth[left] - stamps_s) <= np.abs(sorted_truth[right] - stamps_s), left, right)
    index = order[nearest]
    return np.where(np.abs(sorted_truth[nearest] - stamps_s) <= tolerance_s, index, -1)


def check_fits(predictor: ForcePredictor, sensor: SensorDescription) -> None:
    """BagError unless the model fits the sensor description (artifacts.check_model_fits)."""
    from tactile_fusion.artifacts import ModelFileError, check_model_fits  # imports torch: record and play need none

    try:
        check_model_fits(predictor, sensor)
    except ModelFileError as exc:
        raise BagError(f"{exc} (--model, --sensor)") from exc


def live_estimation(predictor: ForcePredictor, sensor: SensorDescription, reference_bundles: int) -> LiveEstimation:
    """fusion_node's loop for the bag, or BagError when the model does not fit the sensor description."""
    check_fits(predictor, sensor)
    return LiveEstimation(predictor, sensor, reference_bundles)


def evaluate_bag(path: str | Path, sensor: SensorDescription, predictor: ForcePredictor, source: str = "auto",
                 reference_bundles: int = REFERENCE_BUNDLES, truth_topic: str | None = None,
                 match_tolerance_s: float = MATCH_TOLERANCE_S,
                 contact_level_n: float = CONTACT_LEVEL_N, namespace: str = ROOT_NAMESPACE) -> BagEvaluation:
    """Estimate the force of every bundle of the bag after the reference ones and match the ground truth.

    truth_topic: None for the simulator's (optional in the bag); a topic named here must be in the bag.
    contact_level_n: the estimated total Fz from which an estimate reports contact (metrics' "contact").
    namespace: of the graph whose topics are evaluated (its images or bundles, and the simulator's ground truth).
    """
    live = live_estimation(predictor, sensor, reference_bundles)
    simulator_truth = in_namespace(GROUND_TRUTH_TOPIC, namespace)
    with BagReader(path) as bag:
        source = choose_source(bag, sensor, source, namespace)
        # Images of cameras the description does not name are not read: those of another sensor's description, or
        # of the graph in another namespace, say (left out without a word before; review)
        cameras = camera_topics(sensor, namespace)
        other_images = tuple(sorted(t for t, kind in bag.topics.items()
                                    if kind == IMAGE_TYPE and t not in cameras and bag.counts[t]))
        reader = FrameReader(sensor, predictor.image_size)
        try:
            truth_stamps, truth = read_ground_truth(bag, sensor, truth_topic or simulator_truth,
                                                    required=truth_topic is not None)
        except DefinitionMismatchError:
            if truth_topic is not None:
                raise
            # The simulator's ground truth is optional: a bag recorded before ForceDistribution changed is still
            # evaluated, without it, and the summary says why it has no metrics.
            reason = f"ground truth on {simulator_truth} recorded with another ForceDistribution definition"
            reader.skipped[reason] = bag.counts[simulator_truth]
            truth_stamps, truth = no_ground_truth(sensor)
        frames = (image_bundles(bag, sensor, reader, namespace) if source == "images"
                  else recorded_bundles(bag, reader, namespace))
        bundles = after_reference = 0
        stamps, estimates, camera_ok, off_reference = [], [], [], []
        for frame in frames:
            bundles += 1
            if frame.unusable:  # counted as skipped by the reader; not a frame of the reference either
                continue
            result = live.add(frame.images, frame.camera_ok)
            if result.for_reference:
                continue
            after_reference += 1
            if result.forces is None:
                reader.skip("bundle without any usable image")
                continue
            estimates.append(result.forces)
            stamps.append(frame.stamp_s)
            camera_ok.append(result.camera_ok)
            if live.match is not None:
                off_reference.append(live.match.off.copy())
    reference = live.reference
    if reference.images is None:
        # Which bundles could not be used says more than the remedy for a short recording: a bag of another sensor has
        # no usable bundle at all (review).
        skipped = "".join(f"; {count} {reason}" for reason, count in reader.skipped.items())
        raise BagError(f"bag {path}: only {reference.frames_taken} complete bundle(s) of {bundles}{skipped}, the "
                       f"reference frames need {reference_bundles}; record longer at rest first, or lower "
                       f"--reference-bundles (the reference does without a camera that has no usable image after "
                       f"{reference.patience} bundles)")
    if not after_reference:
        raise BagError(f"bag {path}: the reference frames took every complete bundle of its {bundles}, none is left to "
                       "estimate; record longer, or lower --reference-bundles")
    stamps_s = np.asarray(stamps, dtype=np.float64)
    return BagEvaluation(
        bag=str(path), source=source, camera_ids=sensor.camera_ids, bundles=bundles,
        reference_bundles=reference_bundles, stamps_s=stamps_s,
        estimates_n=np.stack(estimates) if estimates else np.zeros((0, sensor.grid.rows, sensor.grid.cols, 3),
                                                                    np.float32),
        camera_ok=np.array(camera_ok, bool).reshape(len(stamps), sensor.n_cameras),
        off_reference=(np.array(off_reference, bool).reshape(len(stamps), sensor.n_cameras) if live.match is not None
                       else None),
        reference_cameras=reference.cameras,
        truth_messages=len(truth_stamps), truth_index=match_stamps(stamps_s, truth_stamps, match_tolerance_s),
        truth_n=truth, bin_centers_m=sensor.grid.bin_centers_m(), skipped=reader.skipped,
        contact_level_n=contact_level_n, other_image_topics=other_images)
