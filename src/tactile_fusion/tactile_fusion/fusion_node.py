"""ROS node: tactile_msgs/ImageBundle -> force distribution, total wrench and RViz markers.

Subscribes `/tactile/image_bundle`; publishes `/tactile/force_distribution` (tactile_msgs/ForceDistribution),
`/tactile/wrench` (geometry_msgs/WrenchStamped) and `/tactile/force_markers` (visualization_msgs/MarkerArray),
all stamped with the capture time of the bundle.

Reference frames: the model sees each camera's difference to a frame taken at rest. At start-up (and on the
`~/capture_reference` service, std_srvs/Trigger) the node averages the next `reference_bundles` complete
bundles, assuming nothing touches the surface meanwhile; it publishes nothing until it has them. While a camera
holds the capture up it says which (every 5 s); after `live_estimation.REFERENCE_PATIENCE_BUNDLES` bundles without
enough complete ones it takes the reference without that camera, whose images are then not used until the next
capture (live_estimation.ReferenceFrames). The frames go through `live_estimation.LiveEstimation`, the loop that
`tactile-bag eval` runs too.

RViz markers (one line per loaded bin, `tactile_conversions.forces.force_markers`) cost 2-5 ms to build and
serialise with every bin loaded, more than an inference (about 1 ms). A display needs no more than
`markers_rate_hz` (default 10) of them a second. The first markers, one arrow marker per bin, took about 40 ms:
published with every estimate at the sensor's 40 Hz they made the node fall behind its bundles (estimates up to
184 ms old, `tactile-latency`).

Lost bundles: the bundle node numbers its bundles; a jump in the numbers is logged as "lost N bundle(s)" (every
10 s at most, with the count since start), so that a full subscription queue does not drop bundles silently.

Degraded input: a camera missing from a bundle, or whose image is unreadable, is marked not ok for the predictor
(which shows the model that camera at rest, tactile_fusion.camera_out: "no contact"), and the estimate lists it in
`missing_camera_ids`. Every problem of a bundle is logged in one line (every 5 s at most, with the count of such
bundles since start), so that each broken camera is named; a malformed bundle (not one image per camera id) and a
bundle of another sensor (a camera the sensor description does not name) are skipped (images.bundle_problem).
"""

from __future__ import annotations

import time

import torch
from geometry_msgs.msg import WrenchStamped
from rclpy.node import Node
from std_srvs.srv import Trigger
from visualization_msgs.msg import MarkerArray

from tactile_conversions.forces import force_distribution_msg, force_markers, wrench_msg
from tactile_conversions.images import bundle_problem, frame_from_images
from tactile_conversions.node_main import run_node
from tactile_conversions.parameters import (
    ParameterError,
    boolean,
    log_sensor_description,
    rate_hz,
    refused_as,
    sensor_description,
    text,
    whole_number,
)
from tactile_conversions.ros_time import is_ros_stamp, time_to_seconds
from tactile_conversions.topics import BUNDLE_TOPIC, ESTIMATE_TOPIC, MARKERS_TOPIC, WRENCH_TOPIC, node_topic
from tactile_description import left_out_components
from tactile_fusion.artifacts import (
    ModelFileError,
    default_model_dir,
    sensor_changes,
    sensor_changes_warning,
    threshold_text,
)
from tactile_fusion.inference import DEFAULT_THREADS, MAX_THREADS, InputError, check_backend, load_predictor
from tactile_fusion.live_estimation import (
    MAX_REFERENCE_BUNDLES,
    REFERENCE_BUNDLES,
    BundleSequence,
    FrameResult,
    FrozenCameras,
    LiveEstimation,
    ProcessingLoad,
)
from tactile_msgs.msg import ForceDistribution, ImageBundle

#: Default `markers_rate_hz`: enough for a display (see above).
MARKERS_RATE_HZ = 10.0


class FusionNode(Node):
    def __init__(self) -> None:
        super().__init__("tactile_fusion")
        model_dir = text(self, "model_dir", "")
        backend = text(self, "backend", "onnxruntime")
        precision = text(self, "precision", "fp32")
        threads = whole_number(self, "threads", DEFAULT_THREADS, high=MAX_THREADS)
        reference_bundles = whole_number(self, "reference_bundles", REFERENCE_BUNDLES, high=MAX_REFERENCE_BUNDLES)
        self.publish_markers = boolean(self, "publish_markers", True)
        try:
            markers_rate_hz = rate_hz(self, "markers_rate_hz", MARKERS_RATE_HZ)
        except ParameterError as exc:  # the remedy only where it is not taken already (review)
            raise (ParameterError(f"{exc} (to publish no markers, set publish_markers false)") if self.publish_markers
                   else exc) from exc
        self.markers_period_s = 1.0 / markers_rate_hz
        self.last_markers_s = -float("inf")
        with refused_as(self, "parameters backend and precision", ValueError):
            check_backend(backend, precision)
        self.sensor = sensor_description(self)
        # A model directory that is missing, damaged, of two models mixed, or of another sensor; left empty, the
        # shipped model, which the refusal names: it is for the reference sensor only.
        where = f"parameter model_dir{'' if model_dir else f' (empty: the shipped model, {default_model_dir()})'}"
        with refused_as(self, where, ModelFileError):
            self.predictor = load_predictor(model_dir or None, backend, precision, threads)
            self.live = LiveEstimation(self.predictor, self.sensor, reference_bundles)
        # The reference check (live_estimation.mismatch_levels) runs in torch whatever the backend: on torch's default
        # of every core, beside other busy processes, a check took 128 ms instead of 0.8 ms (review).
        torch.set_num_threads(threads)
        self.image_shape = (self.predictor.image_size, self.predictor.image_size)
        self.bundles_with_problems = 0
        self.cameras_in_bundles: set[str] = set()  # every camera id a bundle has held (other_sensor_hint)
        self.load = ProcessingLoad(1.0 / self.sensor.frame_rate_hz)
        self.sequence = BundleSequence()
        self.forces_pub = self.create_publisher(ForceDistribution, node_topic(ESTIMATE_TOPIC), 10)
        self.wrench_pub = self.create_publisher(WrenchStamped, node_topic(WRENCH_TOPIC), 10)
        self.markers_pub = self.create_publisher(MarkerArray, node_topic(MARKERS_TOPIC), 10)
        self.create_subscription(ImageBundle, node_topic(BUNDLE_TOPIC), self.on_bundle, 10)
        self.create_service(Trigger, "~/capture_reference", self.on_capture_reference)
        log_sensor_description(self, self.sensor)
        self.get_logger().info(f"{backend} {precision} model for cameras {list(self.sensor.camera_ids)}; capturing "
                               f"the reference from the next {reference_bundles} bundles: do not touch")
        changed = sensor_changes_warning(sensor_changes(self.predictor.made_for, self.sensor), self.sensor)
        if changed:
            self.get_logger().warning(changed)
        left_out = left_out_components(self.predictor.components)
        if left_out:
            self.get_logger().warning(f"the model estimates {', '.join(self.predictor.components)} only: "
                                      f"{', '.join(left_out)} are published as 0 (its training data had none)")
        if self.predictor.fz_threshold_n is not None:
            threshold = threshold_text(self.predictor.fz_threshold_n)
            self.get_logger().info(f"Fz per bin below {threshold} is published as 0 (the model's Fz threshold)")

    def on_capture_reference(self, _request, response):
        self.live.reset()
        response.success = True
        response.message = f"capturing the reference from the next {self.live.reference.count} complete bundles"
        return response

    def on_bundle(self, bundle: ImageBundle) -> None:
        started = time.perf_counter()
        self.count_lost_bundles(bundle.sequence)
        stamp = bundle.header.stamp
        if not is_ros_stamp(stamp):  # the bundle node never sends one; a bag or another publisher may
            self.report_problems(bundle.sequence, [("stamp outside [0, 2**31) s", f"sec {stamp.sec}, nanosec "
                                                    f"{stamp.nanosec}, which no estimate can carry; the bundle is "
                                                    "skipped")])
            return  # neither estimated nor counted towards the reference frames
        self.estimate(bundle)
        if self.load.add(time.perf_counter() - started, time_to_seconds(stamp)):
            self.get_logger().warning(
                f"falling behind the cameras: a bundle takes {1e3 * self.load.mean_s:.1f} ms on average, they come "
                f"every {1e3 * self.load.period_s:.1f} ms, so estimates arrive later and later; a faster backend "
                "or precision (tactile-fusion bench), a lower markers_rate_hz or publish_markers false help",
                throttle_duration_sec=10.0)

    def count_lost_bundles(self, sequence: int) -> None:
        restarts = self.sequence.restarts
        lost = self.sequence.add(sequence)
        if self.sequence.restarts > restarts:
            self.get_logger().info(f"bundle numbers start over at {sequence}: the bundle node restarted, or a bag "
                                   "replay started again (or two nodes publish bundles)", throttle_duration_sec=10.0)
        if lost:
            self.get_logger().warning(
                f"lost {lost} bundle(s) before bundle {sequence} ({self.sequence.lost} since start): this node's "
                "subscription queue overflowed because it is slower than the cameras, the network dropped them, or a "
                "replayed bag lacks them",
                throttle_duration_sec=10.0)

    def estimate(self, bundle: ImageBundle) -> None:
        """Capture the reference or publish the estimate of one bundle."""
        whole = bundle_problem(bundle.camera_ids, bundle.images, self.sensor.camera_ids)
        if whole is not None:
            self.report_problems(bundle.sequence, [whole])
            return  # neither estimated nor counted towards the reference frames
        images, camera_ok, problems = frame_from_images(bundle.camera_ids, bundle.images, self.sensor.camera_ids,
                                                        self.image_shape)
        self.cameras_in_bundles.update(bundle.camera_ids)
        try:
            result = self.live.add(images, camera_ok)
        except (InputError, FloatingPointError) as exc:
            self.report_problems(bundle.sequence, problems)
            self.get_logger().error(f"no estimate for this bundle: {exc}", throttle_duration_sec=5.0)
            return
        if result.for_reference:  # report_reference names the cameras missing meanwhile
            self.report_problems(bundle.sequence, problems)
            self.report_reference(result)
            return
        absent = [c for c in self.sensor.camera_ids if c not in bundle.camera_ids]
        if absent:  # an empty bundle too, of which nothing is published
            problems.append((f"no image of {', '.join(absent)}", "missing from the bundle: the bundle node leaves out "
                             "a camera that fell silent (its log says since when)" + self.other_sensor_hint(absent)))
        self.report_problems(bundle.sequence, problems)
        self.report_reference_match(result.match_changed)
        self.report_frozen(result.frozen_changed)
        if result.unreferenced.any():
            self.get_logger().warning(
                f"images of {self.camera_names(result.unreferenced)} arrive again, but the reference frames were taken "
                "without them: they are not used until the reference is taken again, with nothing on the surface: "
                f"{self.capture_command()}", throttle_duration_sec=10.0)
        if result.forces is not None:
            self.publish(bundle, result)

    def report_problems(self, sequence: int, problems: list[tuple[str, str]]) -> None:
        """Every problem of one bundle in one line, so that each broken camera is named (every 5 s at most)."""
        if not problems:
            return
        self.bundles_with_problems += 1
        self.get_logger().error(
            f"bundle {sequence}: " + "; ".join(f"{reason} ({detail})" for reason, detail in problems)
            + f" ({self.bundles_with_problems} bundle(s) with missing or unusable images since start)",
            throttle_duration_sec=5.0)

    def publish(self, bundle: ImageBundle, result: FrameResult) -> None:
        """The estimate of one bundle on the force, wrench and (at their rate) marker topics."""
        present = [c for c, ok in zip(self.sensor.camera_ids, result.camera_ok, strict=True) if ok]
        missing = [c for c, ok in zip(self.sensor.camera_ids, result.camera_ok, strict=True) if not ok]
        try:
            distribution = force_distribution_msg(result.forces, self.sensor.grid, bundle.header.stamp,
                                                  self.sensor.frame_id, present, missing, self.predictor.components)
        except ValueError as exc:  # a model whose graph outputs forces its model.json says it does not estimate
            self.get_logger().error(f"no estimate published: {exc}", throttle_duration_sec=5.0)
            return
        self.forces_pub.publish(distribution)
        self.wrench_pub.publish(wrench_msg(distribution))
        now_s = time.monotonic()
        if self.publish_markers and now_s - self.last_markers_s >= self.markers_period_s:
            self.last_markers_s = now_s
            self.markers_pub.publish(force_markers(result.forces, self.sensor.grid, bundle.header.stamp,
                                                   self.sensor.frame_id,
                                                   lifetime_s=max(1.0, 2.0 * self.markers_period_s)))

    def report_reference(self, result: FrameResult) -> None:
        """Say that the reference is taken, and without which cameras, or which cameras hold it up."""
        reference = self.live.reference
        if not result.reference_taken:
            if not result.camera_ok.all():
                self.get_logger().warning(
                    f"capturing the reference: no usable image of {self.camera_names(~result.camera_ok)} "
                    f"({reference.frames_taken} of {reference.count} complete bundles so far); after "
                    f"{reference.patience} bundles it is taken without the cameras missing from the last "
                    f"{reference.count}, which are then not used until it is taken again"
                    + self.other_sensor_hint(c for c, ok in zip(self.sensor.camera_ids, result.camera_ok, strict=True)
                                             if not ok), throttle_duration_sec=5.0)
            return
        if reference.cameras.all():
            self.get_logger().info("reference frames captured: publishing forces")
        else:
            self.get_logger().warning(
                f"reference frames captured without {self.camera_names(~reference.cameras)} ({reference.patience} "
                f"bundles brought fewer than {reference.count} complete ones): publishing forces without them (listed "
                "as missing); once they give images again, take the reference again, with nothing on the surface: "
                f"{self.capture_command()}")
        if reference.rest_levels is None:
            self.get_logger().info("a reference of one bundle: whether the cameras still match it is not "
                                   "checked (reference_bundles of 2 or more for that)")
        elif reference.still.any():
            self.get_logger().warning(
                f"the images of {self.camera_names(reference.still)} did not change at all over the {reference.count} "
                "reference bundles: a frozen camera, a still image or video as the source, a covered lens or an unlit "
                "LED (or a scene simulated without sensor noise); while an image equals its reference it is shown at "
                "rest, whatever is on the surface")

    def report_reference_match(self, changed) -> None:
        """Say when a camera's images stop or start again to match its reference frame (live_estimation.
        ReferenceMatch)."""
        match = self.live.match
        for camera in changed:
            name = self.sensor.camera_ids[camera]
            level = match.level(camera)
            if match.off[camera]:
                self.get_logger().warning(
                    f"{name}'s images no longer match its reference frame ({level:.1f} grey levels of difference at "
                    f"the 75th percentile, {self.live.reference.rest_levels[camera]:.1f} when it was taken): the "
                    "camera moved or was refocused, or the gel aged, and the estimates err several times more; with "
                    f"nothing on the surface, take the reference again: {self.capture_command()}")
            else:
                self.get_logger().info(f"{name}'s images match its reference frame again ({level:.1f} grey levels)")

    def report_frozen(self, changed) -> None:
        """Say when a camera starts or stops sending the same image again and again (live_estimation.FrozenCameras)."""
        for camera in changed:
            name = self.sensor.camera_ids[camera]
            if self.live.frozen.frozen[camera]:
                self.get_logger().warning(
                    f"{name} has sent the same image, pixel for pixel, for {FrozenCameras.FRAMES} bundles: the camera "
                    "or its driver is stuck, its source is a still image, or its lens is covered; its part of the "
                    "estimates does not follow the surface (it stays in camera_ids)")
            else:
                self.get_logger().info(f"{name}'s images change again")

    def other_sensor_hint(self, cameras) -> str:
        """For cameras that no bundle has held since start: the bundle node may bundle another sensor's cameras (it
        ran with another sensor_config), which its own log, naming the cameras it bundles, shows; "" for none."""
        never = [c for c in cameras if c not in self.cameras_in_bundles]
        if not never:
            return ""
        return (f"; no bundle has held {', '.join(never)} since this node started: dead since, or the bundle node "
                f"runs with another sensor description than this node's {self.sensor.source} (its log names the "
                "cameras it bundles)")

    def camera_names(self, mask) -> str:
        return ", ".join(c for c, m in zip(self.sensor.camera_ids, mask, strict=True) if m)

    def capture_command(self) -> str:
        return f"ros2 service call {self.get_fully_qualified_name()}/capture_reference std_srvs/srv/Trigger"


def main(args: list[str] | None = None) -> None:
    run_node(FusionNode, args)
