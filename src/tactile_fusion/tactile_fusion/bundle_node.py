"""ROS node: camera images -> tactile_msgs/ImageBundle, with the approximate-time synchroniser.

Subscribes `/tactile/<camera_id>/image` for every camera of the sensor description and publishes
`/tactile/image_bundle`, numbering the bundles (`sequence`: 0, 1, 2, ...) so that a subscriber can tell when it
lost some. A camera that falls silent for `camera_timeout_s` is left out of the bundles (they
then list fewer cameras, and the fusion node reports it as missing) until it sends images again, so one broken
camera degrades the estimate instead of stopping it.

Nothing is dropped silently: what the synchroniser drops (approximate_sync.SyncCounters: late, overflowing, too
wide, superseded images, and those it held when it reset) is logged with its reasons and cameras at once, then
every `DROP_LOG_PERIOD_S` at most while it goes on, and when the node stops. A camera whose stamps jump back by
more than two frame periods (a bag replay that loops, a clock set back, a restarted camera) makes the
synchroniser start over from the new stamps, with a warning; without that, every later image would be dropped as
out of order until the stamps passed the old ones again.

A camera whose frame rate does not fit the synchronisation settings, whose defaults follow the sensor description's
frame rate (a camera node run at its own `rate_hz`, a camera that cannot keep up), is named once with its rate, what
goes wrong and the remedy (`camera_rates`): before, it showed only as cameras lost and back with every frame, or as
`too_wide` drops.

An image whose stamp no bundle can carry (`ros_time.is_ros_time`: a negative `sec`, legal in a message, or one past
2**31 s) is dropped before it reaches the synchroniser, counted as `bad_stamp` and logged every `DROP_LOG_PERIOD_S` at
most; it does not count as a sign of life of its camera, so a camera that sends only such images is left out.
"""

from __future__ import annotations

import statistics
import time

from rclpy.node import Node
from rclpy.qos import qos_profile_sensor_data
from sensor_msgs.msg import Image
from std_msgs.msg import Header

from tactile_conversions.node_main import run_node
from tactile_conversions.parameters import (
    log_sensor_description,
    period_s,
    positive_float,
    sensor_description,
    whole_number,
)
from tactile_conversions.ros_time import is_ros_time, seconds_to_time, time_to_seconds
from tactile_conversions.timers import steady_timer
from tactile_conversions.topics import BUNDLE_TOPIC, camera_topic, node_topic
from tactile_fusion.approximate_sync import ApproximateTimeSync, Bundle, SyncCounters, camera_sync_settings
from tactile_fusion.camera_arrivals import CameraArrivals
from tactile_fusion.camera_rates import CameraPeriods, SyncSettings, period_misfits
from tactile_msgs.msg import ImageBundle

#: While the synchroniser drops images, what it dropped is logged at once and then at most this often (seconds).
DROP_LOG_PERIOD_S = 10.0
#: A camera whose measured rate is within this fraction of the description's runs at it: where its period does not fit
#: the settings in force, those were given to the node, and the remedy is not another frame_rate_hz.
DESCRIBED_RATE_TOLERANCE = 0.05


#: The shortest period of the check for silent cameras (s). Half the timeout otherwise; the smallest timeout, 1 ms, made
#: a 2 kHz timer that held a third of a core (review), while no camera can be declared silent faster than its frames
#: come. A camera is then found silent within the timeout plus this.
CAMERA_CHECK_MIN_PERIOD_S = 0.01


class BundleNode(Node):
    def __init__(self) -> None:
        super().__init__("tactile_bundle")
        self.dropped = SyncCounters()  # by every synchroniser of the node; first: destroy_node reports it
        self.reported = self.dropped.snapshot()
        self.last_report_s = -float("inf")
        self.sensor = sensor_description(self)
        defaults = camera_sync_settings(self.sensor.frame_rate_hz)
        self.max_spread_s = positive_float(self, "max_spread_s", defaults["max_spread_s"])
        self.queue_size = whole_number(self, "queue_size", defaults["queue_size"])
        self.min_period_s = positive_float(self, "min_period_s", defaults["min_period_s"], allow_zero=True)
        self.keep_grouping_s = positive_float(self, "keep_grouping_s", defaults["keep_grouping_s"], allow_zero=True)
        self.camera_timeout_s = period_s(self, "camera_timeout_s", 10 / self.sensor.frame_rate_hz)
        self.restart_jump_s = defaults["restart_jump_s"]
        self.publisher = self.create_publisher(ImageBundle, node_topic(BUNDLE_TOPIC), 10)
        self.arrivals = CameraArrivals(self.sensor.camera_ids)
        self.arrival_clock_simulated = self.get_clock().ros_time_is_active
        self.live_cameras: tuple[str, ...] = ()
        self.lost_cameras: set[str] = set()
        self.sync: ApproximateTimeSync[Image] | None = None
        self.sequence = 0
        self.camera_periods = CameraPeriods()
        self.sync_settings = SyncSettings(len(self.sensor.camera_ids), self.max_spread_s, self.min_period_s,
                                          self.camera_timeout_s)
        self.named_rates: set[str] = set()  # cameras whose rate was named in the log
        for camera_id in self.sensor.camera_ids:
            self.create_subscription(Image, node_topic(camera_topic(camera_id)),
                                     lambda msg, c=camera_id: self.on_image(c, msg), qos_profile_sensor_data)
        steady_timer(self, max(self.camera_timeout_s / 2, CAMERA_CHECK_MIN_PERIOD_S), self.check_cameras)
        steady_timer(self, 1.0, self.report_drops)
        log_sensor_description(self, self.sensor)
        self.get_logger().info(f"bundling cameras {list(self.sensor.camera_ids)} "
                               f"(max spread {self.max_spread_s * 1e3:.1f} ms, a grouping kept while within "
                               f"{self.keep_grouping_s * 1e3:.1f} ms of the tightest)")

    def destroy_node(self) -> None:
        """Destroy the node, then log the last drops, however recent the previous report. A Ctrl-C or SIGTERM has
        shut the context down by now, so a line logged before failed to reach /rosout ("Failed to publish log message
        to rosout: publisher's context is invalid"); with the node, its /rosout publisher is gone, and the line goes
        to the console and the log file only."""
        super().destroy_node()
        self.log_drops()

    def now_s(self) -> float:
        """Arrival time, by which a camera is found silent: the simulated clock's with use_sim_time (a bag played
        slower, or paused, is judged in its own time; its steps back and its 0 before the first /clock are
        CameraArrivals'), the steady clock's otherwise. On the system clock an NTP step longer than camera_timeout_s
        counted every camera silent once, and a step back kept a silent one live for its length (review). rclpy lets
        use_sim_time change while the node runs: the arrivals are then carried over to the other clock."""
        clock = self.get_clock()
        simulated = clock.ros_time_is_active
        if simulated != self.arrival_clock_simulated:
            self.arrival_clock_simulated = simulated
            self.arrivals.clock_changed()
            self.get_logger().info(f"use_sim_time is now {str(simulated).lower()}: a camera's silence is timed on the "
                                   f"{'simulated' if simulated else 'steady'} clock from now on")
        return clock.now().nanoseconds * 1e-9 if simulated else time.monotonic()

    def on_image(self, camera_id: str, msg: Image) -> None:
        stamp_s = time_to_seconds(msg.header.stamp)
        if not is_ros_time(stamp_s):
            self.drop_bad_stamp(camera_id, msg)
            return
        self.check_rate(camera_id, stamp_s)
        now = self.now_s()
        if not self.live_cameras:
            # First image since start-up (or since every camera fell silent): give every camera one timeout to
            # show up, so that the first bundles hold all cameras that work rather than whichever came first.
            self.arrivals.arrived(self.sensor.camera_ids, now)
        self.arrivals.arrived([camera_id], now)
        if camera_id not in self.live_cameras:
            self.check_cameras()
        if self.sync is None or camera_id not in self.live_cameras:
            return
        for bundle in self.sync.add(camera_id, stamp_s, msg):
            self.publisher.publish(self.to_msg(bundle, self.sequence))
            self.sequence += 1

    def drop_bad_stamp(self, camera_id: str, msg: Image) -> None:
        """Count and log an image whose stamp no bundle could carry: the bundle's stamp (their median) is written
        back into a Time, which would fail (negative) or wrap round to a negative `sec` (2**31 s or later)."""
        self.dropped.drop_bad_stamp(camera_id)
        stamp = msg.header.stamp
        self.get_logger().warning(
            f"{camera_id}: dropped an image stamped sec={stamp.sec} nanosec={stamp.nanosec}: a bundle's stamp must "
            f"lie in [0, 2**31) s; {self.dropped.bad_stamp} such image(s) since start",
            throttle_duration_sec=DROP_LOG_PERIOD_S)

    def check_rate(self, camera_id: str, stamp_s: float) -> None:
        """Name a camera, once, whose frame period does not fit this node's synchronisation settings (camera_rates)."""
        self.camera_periods.add(camera_id, stamp_s)
        period = self.camera_periods.period_s(camera_id)
        if period is None or camera_id in self.named_rates:
            return
        misfits = period_misfits(period, self.sync_settings)
        if misfits:
            self.named_rates.add(camera_id)
            if abs(period * self.sensor.frame_rate_hz - 1.0) <= DESCRIBED_RATE_TOLERANCE:
                remedy = ("The camera runs at the description's rate, so the parameters given to this node do not fit "
                          "it: leave them out (the defaults follow the description), or set them for that rate")
            else:
                remedy = ("Set frame_rate_hz in the sensor description to the cameras' rate (this node's defaults "
                          "follow it), or set those parameters")
            self.get_logger().warning(
                f"{camera_id} captures {1 / period:.3g} frames a second by its stamps, the sensor description says "
                f"{self.sensor.frame_rate_hz:g} Hz: {'; '.join(misfits)}. {remedy}")

    def check_cameras(self) -> None:
        """Rebuild the synchroniser when the set of cameras that send images changes."""
        live = self.arrivals.live(self.now_s(), self.camera_timeout_s)
        if live == self.live_cameras:
            return
        self.log_camera_changes(live)
        if self.sync is not None:
            self.sync.reset()  # counts the images it held as dropped
        self.live_cameras = live
        self.sync = ApproximateTimeSync(live, self.queue_size, self.max_spread_s, self.min_period_s,
                                        self.restart_jump_s, self.keep_grouping_s, self.dropped,
                                        self.on_restart) if live else None

    def log_camera_changes(self, live: tuple[str, ...]) -> None:
        """Warn about cameras that fell silent; say when one of those sends again (not at start-up)."""
        lost = sorted(set(self.live_cameras) - set(live))
        if lost:
            # All silent (a replayed bag ended, the cameras stopped) is no "bundling [] only" (found by a walkthrough)
            bundling = f"bundling {list(live)} only" if live else "no camera sends: no bundles until one does"
            self.get_logger().warning(f"no images from {lost} for {self.camera_timeout_s:.2f} s: {bundling}")
        back = sorted(self.lost_cameras & set(live))
        if back:
            self.get_logger().info(f"cameras {back} are back: bundling {list(live)}")
        self.lost_cameras = (self.lost_cameras | set(lost)) - set(live)

    def on_restart(self, camera_id: str, previous_stamp_s: float, stamp_s: float) -> None:
        self.get_logger().warning(
            f"{camera_id}'s stamps went back {previous_stamp_s - stamp_s:.3f} s (from {previous_stamp_s:.3f} s to "
            f"{stamp_s:.3f} s): a replayed bag started over, the clock was set back or the camera restarted; "
            "synchronising from the new stamps", throttle_duration_sec=DROP_LOG_PERIOD_S)

    def report_drops(self) -> None:
        """Every second: drops are logged at once, then at most every DROP_LOG_PERIOD_S while they go on."""
        if time.monotonic() - self.last_report_s >= DROP_LOG_PERIOD_S:
            self.log_drops()

    def log_drops(self) -> None:
        """Log what the synchroniser dropped since the last time, if anything (reasons: SyncCounters)."""
        if self.dropped.total == self.reported.total:
            return
        new = self.dropped.since(self.reported)
        self.get_logger().warning(f"the synchroniser dropped {new.total} image(s) ({new}), {self.dropped.total} "
                                  "since start")
        self.reported = self.dropped.snapshot()
        self.last_report_s = time.monotonic()

    def to_msg(self, bundle: Bundle[Image], sequence: int) -> ImageBundle:
        return ImageBundle(header=Header(stamp=seconds_to_time(statistics.median(bundle.stamps)),
                                         frame_id=self.sensor.frame_id), sequence=sequence,
                           camera_ids=list(bundle.stream_ids), images=list(bundle.items),
                           max_stamp_spread_s=bundle.spread)


def main(args: list[str] | None = None) -> None:
    run_node(BundleNode, args)
