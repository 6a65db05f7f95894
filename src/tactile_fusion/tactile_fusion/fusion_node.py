"""ROS node: tactile_msgs/ImageBundle -> force distribution, total wrench and RViz markers.

Subscribes `/tactile/image_bundle`; publishes `/tactile/force_distribution` (tactile_msgs/ForceDistribution),
`/tactile/wrench` (geometry_msgs/WrenchStamped) and `/tactile/force_markers` (visualization_msgs/MarkerArray),
all stamped with the capture time of the bundle.

Reference frames: the model sees each camera's difference to a frame taken at rest. At start-up (and on the
`~/capture_reference` service, std_srvs/Trigger) the node averages the next `reference_bundles` complete
bundles, assuming nothing touches the surface meanwhile; it publishes nothing until it has them.

Degraded input: a camera missing from a bundle, or whose image is unreadable, is replaced by its reference
frame (the model sees "no contact" there), and the estimate lists it in `missing_camera_ids`.
"""

from __future__ import annotations

import numpy as np
from geometry_msgs.msg import WrenchStamped
from rclpy.node import Node
from std_srvs.srv import Trigger
from visualization_msgs.msg import MarkerArray

from tactile_conversions.forces import force_distribution_msg, force_markers, wrench_msg
from tactile_conversions.images import ImageMessageError, msg_to_array
from tactile_conversions.node_main import run_node
from tactile_description import load_sensor
from tactile_description.imaging import to_mono8
from tactile_fusion.inference import InputError, load_predictor
from tactile_msgs.msg import ForceDistribution, ImageBundle


class FusionNode(Node):
    def __init__(self) -> None:
        super().__init__("tactile_fusion")
        sensor_config = self.declare_parameter("sensor_config", "").value
        model_dir = self.declare_parameter("model_dir", "").value
        backend = self.declare_parameter("backend", "onnxruntime").value
        precision = self.declare_parameter("precision", "fp32").value
        threads = int(self.declare_parameter("threads", 1).value)
        self.reference_bundles = int(self.declare_parameter("reference_bundles", 10).value)
        self.publish_markers = bool(self.declare_parameter("publish_markers", True).value)
        if self.reference_bundles < 1:
            raise ValueError(f"reference_bundles must be >= 1, got {self.reference_bundles}")
        self.sensor = load_sensor(sensor_config or None)
        self.predictor = load_predictor(model_dir or None, backend, precision, threads)
        if tuple(self.predictor.camera_ids) != self.sensor.camera_ids:
            raise ValueError(f"the model was trained for cameras {list(self.predictor.camera_ids)}, the sensor "
                             f"description has {list(self.sensor.camera_ids)}")
        if (self.predictor.rows, self.predictor.cols) != (self.sensor.grid.rows, self.sensor.grid.cols):
            raise ValueError(f"the model predicts {self.predictor.rows} x {self.predictor.cols} bins, the sensor "
                             f"description has {self.sensor.grid.rows} x {self.sensor.grid.cols}")
        size = self.predictor.image_size
        self.image_shape = (size, size)
        self.reference: np.ndarray | None = None
        self._reference_sum = np.zeros((self.sensor.n_cameras, size, size), np.float64)
        self._reference_count = 0
        self.forces_pub = self.create_publisher(ForceDistribution, "/tactile/force_distribution", 10)
        self.wrench_pub = self.create_publisher(WrenchStamped, "/tactile/wrench", 10)
        self.markers_pub = self.create_publisher(MarkerArray, "/tactile/force_markers", 10)
        self.create_subscription(ImageBundle, "/tactile/image_bundle", self.on_bundle, 10)
        self.create_service(Trigger, "~/capture_reference", self.on_capture_reference)
        self.get_logger().info(f"{backend} {precision} model for cameras {list(self.sensor.camera_ids)}; capturing "
                               f"the reference from the next {self.reference_bundles} bundles: do not touch")

    def on_capture_reference(self, _request, response):
        self.reference = None
        self._reference_sum[:] = 0
        self._reference_count = 0
        response.success = True
        response.message = f"capturing the reference from the next {self.reference_bundles} complete bundles"
        return response

    def read_images(self, bundle: ImageBundle) -> tuple[np.ndarray, list[str]]:
        """The bundle's images in the sensor's camera order, and the cameras that gave no usable image."""
        images = np.zeros((self.sensor.n_cameras, *self.image_shape), np.uint8)
        present = set()
        for camera_id, msg in zip(bundle.camera_ids, bundle.images, strict=False):
            if camera_id not in self.sensor.camera_ids:
                self.get_logger().warning(f"bundle holds an image of unknown camera {camera_id!r}: ignored",
                                          throttle_duration_sec=5.0)
                continue
            try:
                image = to_mono8(msg_to_array(msg, camera_id), camera_id)
            except (ImageMessageError, ValueError) as exc:
                self.get_logger().error(f"unusable image: {exc}", throttle_duration_sec=5.0)
                continue
            if image.shape != self.image_shape:
                self.get_logger().error(f"{camera_id}: image is {image.shape[1]} x {image.shape[0]}, the model "
                                        f"needs {self.image_shape[1]} x {self.image_shape[0]}",
                                        throttle_duration_sec=5.0)
                continue
            images[self.sensor.camera_ids.index(camera_id)] = image
            present.add(camera_id)
        return images, [c for c in self.sensor.camera_ids if c not in present]

    def on_bundle(self, bundle: ImageBundle) -> None:
        images, missing = self.read_images(bundle)
        if self.reference is None:
            if not missing:
                self._reference_sum += images
                self._reference_count += 1
                if self._reference_count == self.reference_bundles:
                    self.reference = np.rint(self._reference_sum / self._reference_count).astype(np.uint8)
                    self.get_logger().info("reference frames captured: publishing forces")
            return
        if len(missing) == self.sensor.n_cameras:
            return
        for camera_id in missing:
            i = self.sensor.camera_ids.index(camera_id)
            images[i] = self.reference[i]
        try:
            forces = self.predictor.predict(images, self.reference)
        except (InputError, FloatingPointError) as exc:
            self.get_logger().error(f"no estimate for this bundle: {exc}", throttle_duration_sec=5.0)
            return
        present = [c for c in self.sensor.camera_ids if c not in missing]
        distribution = force_distribution_msg(forces, self.sensor.grid, bundle.header.stamp, self.sensor.frame_id,
                                              present, missing)
        self.forces_pub.publish(distribution)
        self.wrench_pub.publish(wrench_msg(distribution))
        if self.publish_markers:
            self.markers_pub.publish(force_markers(forces, self.sensor.grid, bundle.header.stamp,
                                                   self.sensor.frame_id))


def main(args: list[str] | None = None) -> None:
    run_node(FusionNode, args)
