"""ROS node: tactile_msgs/ImageBundle -> force distribution, total wrench and RViz markers.

Subscribes `/tactile/image_bundle`; publishes `/tactile/force_distribution` (tactile_msgs/ForceDistribution),
`/tactile/wrench` (geometry_msgs/WrenchStamped) and `/tactile/force_markers` (visualization_msgs/MarkerArray),
all stamped with the capture time of the bundle.

Reference frames: the model sees each camera's difference to a frame taken at rest. At start-up (and on the
`~/capture_reference` service, std_srvs/Trigger) the node averages the next `reference_bundles` complete
bundles, assuming nothing touches the surface meanwhile; it publishes nothing until it has them.

RViz markers (one line per loaded bin, `tactile_conversions.forces.force_markers`) cost 2-5 ms to build and
serialise with every bin loaded, more than an inference (about 1 ms). A display needs no more than
`markers_rate_hz` (default 10) of them a second. The first markers, one arrow marker per bin, took about 40 ms:
published with every estimate at the sensor's 40 Hz they made the node fall behind its bundles (estimates up to
184 ms old, `tactile-latency`).

Lost bundles: the bundle node numbers its bundles; a jump in the numbers is logged as "lost N bundle(s)" (every
10 s at most, with the count since start), so that a full subscription queue does not drop bundles silently.

Degraded input: a camera missing from a bundle, or whose image is unreadable, is marked not ok for the predictor
(which shows the model its reference frame there: "no contact"), and the estimate lists it in
`missing_camera_ids`.
"""

from __future__ import annotations

import time

from geometry_msgs.msg import WrenchStamped
from rclpy.node import Node
from std_srvs.srv import Trigger
from visualization_msgs.msg import MarkerArray

from tactile_conversions.forces import force_distribution_msg, force_markers, wrench_msg
from tactile_conversions.images import frame_from_images
from tactile_conversions.node_main import run_node
from tactile_conversions.ros_time import time_to_seconds
from tactile_conversions.topics import BUNDLE_TOPIC, ESTIMATE_TOPIC, MARKERS_TOPIC, WRENCH_TOPIC
from tactile_description import left_out_components, load_sensor
from tactile_fusion.artifacts import check_model_fits, threshold_text
from tactile_fusion.inference import InputError, load_predictor
from tactile_fusion.live_estimation import (
    REFERENCE_BUNDLES,
    BundleSequence,
    ProcessingLoad,
    ReferenceFrames,
    ReferenceMatch,
)
from tactile_msgs.msg import ForceDistribution, ImageBundle

#: Default `markers_rate_hz`: enough for a display (see above).
MARKERS_RATE_HZ = 10.0


class FusionNode(Node):
    def __init__(self) -> None:
        super().__init__("tactile_fusion")
        sensor_config = self.declare_parameter("sensor_config", "").value
        model_dir = self.declare_parameter("model_dir", "").value
        backend = self.declare_parameter("backend", "onnxruntime").value
        precision = self.declare_parameter("precision", "fp32").value
        threads = int(self.declare_parameter("threads", 1).value)
        reference_bundles = int(self.declare_parameter("reference_bundles", REFERENCE_BUNDLES).value)
        self.publish_markers = bool(self.declare_parameter("publish_markers", True).value)
        markers_rate_hz = float(self.declare_parameter("markers_rate_hz", MARKERS_RATE_HZ).value)
        if not markers_rate_hz > 0:
            raise ValueError(f"tactile_fusion: markers_rate_hz must be > 0, got {markers_rate_hz} (to publish no "
                             "markers, set publish_markers false)")
        self.markers_period_s = 1.0 / markers_rate_hz
        self.last_markers_s = -float("inf")
        self.sensor = load_sensor(sensor_config or None)
        self.predictor = load_predictor(model_dir or None, backend, precision, threads)
        check_model_fits(self.predictor, self.sensor)
        self.image_shape = (self.predictor.image_size, self.predictor.image_size)
        self.reference = ReferenceFrames(self.sensor.n_cameras, self.image_shape, reference_bundles)
        self.reference_match: ReferenceMatch | None = None  # once the reference is taken
        self.load = ProcessingLoad(1.0 / self.sensor.frame_rate_hz)
        self.sequence = BundleSequence()
        self.forces_pub = self.create_publisher(ForceDistribution, ESTIMATE_TOPIC, 10)
        self.wrench_pub = self.create_publisher(WrenchStamped, WRENCH_TOPIC, 10)
        self.markers_pub = self.create_publisher(MarkerArray, MARKERS_TOPIC, 10)
        self.create_subscription(ImageBundle, BUNDLE_TOPIC, self.on_bundle, 10)
        self.create_service(Trigger, "~/capture_reference", self.on_capture_reference)
        self.get_logger().info(f"{backend} {precision} model for cameras {list(self.sensor.camera_ids)}; capturing "
                               f"the reference from the next {reference_bundles} bundles: do not touch")
        left_out = left_out_components(self.predictor.components)
        if left_out:
            self.get_logger().warning(f"the model estimates {', '.join(self.predictor.components)} only: "
                                      f"{', '.join(left_out)} are published as 0 (its training data had none)")
        if self.predictor.fz_threshold_n is not None:
            threshold = threshold_text(self.predictor.fz_threshold_n)
            self.get_logger().info(f"Fz per bin below {threshold} is published as 0 (the model's Fz threshold)")

    def on_capture_reference(self, _request, response):
        self.reference.reset()
        self.reference_match = None
        response.success = True
        response.message = f"capturing the reference from the next {self.reference.count} complete bundles"
        return response

    def on_bundle(self, bundle: ImageBundle) -> None:
        started = time.perf_counter()
        self.count_lost_bundles(bundle.sequence)
        self.estimate(bundle)
        if self.load.add(time.perf_counter() - started, time_to_seconds(bundle.header.stamp)):
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
        images, camera_ok, problems = frame_from_images(bundle.camera_ids, bundle.images, self.sensor.camera_ids,
                                                        self.image_shape)
        for reason, detail in problems:
            self.get_logger().error(f"{reason}: {detail}", throttle_duration_sec=5.0)
        if self.reference.images is None:
            if self.reference.add(images, camera_ok):
                self.get_logger().info("reference frames captured: publishing forces")
                if self.reference.rest_levels is None:
                    self.get_logger().info("a reference of one bundle: whether the cameras still match it is not "
                                           "checked (reference_bundles of 2 or more for that)")
                else:
                    self.reference_match = ReferenceMatch(self.reference.rest_levels)
            return
        self.check_reference_match(images, camera_ok)
        if not camera_ok.any():
            return
        try:
            forces = self.predictor.predict(images, self.reference.images, camera_ok=camera_ok)
        except (InputError, FloatingPointError) as exc:
            self.get_logger().error(f"no estimate for this bundle: {exc}", throttle_duration_sec=5.0)
            return
        present = [c for c, ok in zip(self.sensor.camera_ids, camera_ok, strict=True) if ok]
        missing = [c for c, ok in zip(self.sensor.camera_ids, camera_ok, strict=True) if not ok]
        try:
            distribution = force_distribution_msg(forces, self.sensor.grid, bundle.header.stamp, self.sensor.frame_id,
                                                  present, missing, self.predictor.components)
        except ValueError as exc:  # a model whose graph outputs forces its model.json says it does not estimate
            self.get_logger().error(f"no estimate published: {exc}", throttle_duration_sec=5.0)
            return
        self.forces_pub.publish(distribution)
        self.wrench_pub.publish(wrench_msg(distribution))
        now_s = time.monotonic()
        if self.publish_markers and now_s - self.last_markers_s >= self.markers_period_s:
            self.last_markers_s = now_s
            self.markers_pub.publish(force_markers(forces, self.sensor.grid, bundle.header.stamp,
                                                   self.sensor.frame_id,
                                                   lifetime_s=max(1.0, 2.0 * self.markers_period_s)))

    def check_reference_match(self, images, camera_ok) -> None:
        """Say when a camera's images stop or start again to match its reference frame (live_estimation.
        ReferenceMatch)."""
        if self.reference_match is None:
            return
        for camera in self.reference_match.add(images, self.reference.images, camera_ok):
            name = self.sensor.camera_ids[camera]
            level = self.reference_match.level(camera)
            if self.reference_match.off[camera]:
                self.get_logger().warning(
                    f"{name}'s images no longer match its reference frame ({level:.1f} grey levels of difference at "
                    f"the 75th percentile, {self.reference.rest_levels[camera]:.1f} when it was taken): the camera "
                    "moved or was refocused, or the gel aged, and the estimates err several times more; with nothing "
                    f"on the surface, take the reference again: ros2 service call "
                    f"{self.get_fully_qualified_name()}/capture_reference std_srvs/srv/Trigger")
            else:
                self.get_logger().info(f"{name}'s images match its reference frame again ({level:.1f} grey levels)")


def main(args: list[str] | None = None) -> None:
    run_node(FusionNode, args)
