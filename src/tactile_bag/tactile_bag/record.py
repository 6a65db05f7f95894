"""Record topics of the live graph into a bag: raw (serialized) subscriptions, each message stored with its
receive time, as `ros2 bag record` does (messages are never deserialized, so recording costs little CPU).

Topic types: the stack's own topics (tactile_bag.topics) are known in advance, so recording can start before
their publishers; any other topic must have a publisher in the graph within the discovery timeout, which tells
its type.
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import rclpy
from rclpy.event_handler import SubscriptionEventCallbacks
from rclpy.node import Node
from rclpy.qos import QoSPolicyKind, QoSProfile, ReliabilityPolicy

from tactile_bag.bagfile import BagError, BagWriter
from tactile_bag.message_types import MessageTypeError, message_class
from tactile_bag.topics import IMAGE_TYPE, RELIABLE_DEPTH, absolute_topic, qos_profile
from tactile_conversions.stop_signals import until_stop_signal
from tactile_description.command_line import stop_signals_ignored
from tactile_description.value_checks import is_number

#: The QoS of a topic that has a best-effort publisher (recording_qos, Recorder): a reliable subscription matches none.
BEST_EFFORT = QoSProfile(depth=RELIABLE_DEPTH, reliability=ReliabilityPolicy.BEST_EFFORT)


class Recorder(Node):
    """Subscribes every topic raw and writes each message into `bag` as it arrives.

    A best-effort publisher that appears after a topic was subscribed reliably (recording_qos chose reliable delivery
    because every publisher seen then offered it) matches no reliable subscription: its messages were lost without a
    word (review). Its incompatible-QoS event marks the topic, and `take_best_effort_publishers` subscribes it anew,
    best effort, which matches every publisher, after writing what the old subscription still held; the topic is
    listed in `best_effort_topics`. Messages sent while the new subscription is matched (milliseconds on one machine)
    are not recorded. Reliability is the only policy in which a publisher can be incompatible with the recording's
    subscriptions: they ask for volatile durability, no deadline and automatic liveliness, which every publisher
    offers (checked in review with publishers of each other kind).
    """

    def __init__(self, bag: BagWriter, topic_types: dict[str, str], qos: dict[str, QoSProfile]):
        super().__init__("tactile_bag_recorder")
        self.bag = bag
        self.topic_types = topic_types
        self.first_arrival_s: float | None = None  # time.monotonic() of the first message
        self.best_effort_topics: list[str] = []      # subscribed anew, best effort (above)
        self._reliability_refused: list[str] = []    # topics marked by their incompatible-QoS event
        self._subscription_of = {}
        for topic, msgtype in topic_types.items():
            bag.add_topic(topic, msgtype)
            self._subscribe(topic, qos[topic])

    def _subscribe(self, topic: str, qos: QoSProfile) -> None:
        msgtype = self.topic_types[topic]
        events = SubscriptionEventCallbacks(incompatible_qos=lambda info, t=topic: self._on_incompatible(t, info))
        self._subscription_of[topic] = self.create_subscription(
            message_class(msgtype), topic, lambda raw, t=topic, m=msgtype: self.on_message(t, m, raw), qos, raw=True,
            event_callbacks=events)

    def _on_incompatible(self, topic: str, info) -> None:
        if info.last_policy_kind == QoSPolicyKind.RELIABILITY:
            self._reliability_refused.append(topic)

    def take_best_effort_publishers(self) -> None:
        """Subscribe anew, best effort, each topic whose reliable subscription a best-effort publisher could not
        match, once the messages the old subscription holds are written (destroying it dropped them: review).
        Called between spins: not from the event's callback, whose subscription it destroys."""
        for topic in dict.fromkeys(self._reliability_refused):
            old = self._subscription_of[topic]
            with old.handle:
                while (taken := old.handle.take_message(old.msg_type, True)) is not None:
                    self.on_message(topic, self.topic_types[topic], taken[0])
            self.destroy_subscription(old)
            self._subscribe(topic, BEST_EFFORT)
            self.best_effort_topics.append(topic)
        self._reliability_refused.clear()

    def on_message(self, topic: str, msgtype: str, raw: bytes) -> None:
        if self.first_arrival_s is None:
            self.first_arrival_s = time.monotonic()
        self.bag.write(topic, msgtype, self.get_clock().now().nanoseconds, raw)


def resolve_topic_types(node: Node, topics: Sequence[str], known: dict[str, str],
                        discovery_timeout_s: float) -> dict[str, str]:
    """topic -> type name: from `known`, else from the publishers the graph shows within the timeout."""
    types = {t: known[t] for t in topics if t in known}
    deadline = time.monotonic() + discovery_timeout_s
    while len(types) < len(topics):
        graph = dict(node.get_topic_names_and_types())
        for topic in topics:  # a topic with subscribers alone is not taken: its QoS comes from its publishers
            if topic not in types and graph.get(topic) and node.count_publishers(topic):
                if len(graph[topic]) > 1:
                    raise BagError(f"topic {topic} is published with several types {graph[topic]}: cannot record it")
                types[topic] = graph[topic][0]
        if time.monotonic() >= deadline:
            break
        rclpy.spin_once(node, timeout_sec=0.1)
    unknown = [t for t in topics if t not in types]
    if unknown:
        raise BagError(f"unknown topic {', '.join(unknown)}: not a topic of the tactile stack and no publisher seen "
                       f"within {discovery_timeout_s:g} s; check the name or start its publisher first")
    return {t: types[t] for t in topics}


def recording_qos(node: Node, topic_types: dict[str, str], known: dict[str, str]) -> dict[str, QoSProfile]:
    """topic -> the QoS to record it with: the live graph's for the stack's topics (topics.qos_profile); for another
    topic (resolve_topic_types saw a publisher of it), that of its type where every publisher seen offers reliable
    delivery (for an image topic: sensor-data QoS, best effort), else best effort with a queue of RELIABLE_DEPTH: a
    reliable subscription matches no best-effort publisher (one outside the stack was recorded with 0 messages, and
    the tool asked whether the graph was running; found in review). A best-effort publisher that appears only after
    reliable ones were seen is taken by the Recorder, which then subscribes the topic anew, best effort."""
    def reliable(topic: str) -> bool:
        offered = node.get_publishers_info_by_topic(topic)
        return bool(offered) and all(p.qos_profile.reliability == ReliabilityPolicy.RELIABLE for p in offered)

    return {topic: qos_profile(msgtype) if topic in known or reliable(topic) else BEST_EFFORT
            for topic, msgtype in topic_types.items()}


@dataclass(frozen=True)
class Recording:
    counts: dict[str, int]  # messages per topic
    stopped: bool           # by SIGINT or SIGTERM, before its duration (or its wait for a first message) ran out
    other_images: tuple[str, ...] = ()  # image topics the graph showed meanwhile that were not recorded
    best_effort_topics: tuple[str, ...] = ()  # subscribed anew, best effort, for a publisher that came later (Recorder)


def other_image_topics(node: Node, recorded: Sequence[str]) -> tuple[str, ...]:
    """The image topics `node` sees in the graph that are not among `recorded`: those of cameras of another sensor
    description, when the recording's were silent (a graph of cameras 'left' and 'right' recorded with the default
    description's cam0-cam3 gave 0 images and no hint; walkthrough)."""
    return tuple(sorted(topic for topic, types in node.get_topic_names_and_types()  # subscribers' topics too:
                        if IMAGE_TYPE in types and topic not in recorded and node.count_publishers(topic)))


def record(out: str | Path, topics: Sequence[str], known_types: dict[str, str], duration_s: float,
           discovery_timeout_s: float = 2.0, wait_s: float = 10.0) -> Recording:
    """Record `topics` into the new bag `out`; returns the messages per topic and whether a signal stopped it.

    Recording lasts `duration_s` from the first message received (DDS discovery can take a second or more on a
    loaded machine, and the graph may start after the recorder), stops earlier on SIGINT/SIGTERM, and gives up
    when no message arrives within `wait_s`. rclpy must be initialised by the caller. The bag is closed
    (complete and readable) however recording ends.
    """
    if not (is_number(duration_s) and duration_s > 0 and is_number(wait_s) and wait_s > 0):
        raise ValueError(f"--duration and --wait must be finite numbers > 0 seconds, got {duration_s!r} and "
                         f"{wait_s!r}")
    out = Path(out)
    if out.exists():
        raise BagError(f"{out} already exists: name a new bag directory (a bag is never overwritten)")
    topics = list(dict.fromkeys(absolute_topic(t) for t in topics))
    probe = Node("tactile_bag_discovery")
    try:
        topic_types = resolve_topic_types(probe, topics, known_types, discovery_timeout_s)
        qos = recording_qos(probe, topic_types, known_types)
    finally:
        probe.destroy_node()
    try:
        for msgtype in set(topic_types.values()):
            message_class(msgtype)
    except MessageTypeError as exc:
        raise BagError(f"cannot record: {exc}") from exc
    with BagWriter(out) as bag:
        recorder = Recorder(bag, topic_types, qos)
        give_up = time.monotonic() + wait_s
        other_images: tuple[str, ...] = ()  # none named after a stop: rclpy's context may be shut down by then
        with until_stop_signal() as stop:
            try:
                while True:
                    first = recorder.first_arrival_s
                    left_s = (first + duration_s if first is not None else give_up) - time.monotonic()
                    if left_s <= 0:
                        break
                    rclpy.spin_once(recorder, timeout_sec=min(0.1, left_s))
                    recorder.take_best_effort_publishers()
                other_images = other_image_topics(recorder, topics)
            finally:
                recorder.destroy_node()
        with stop_signals_ignored():  # an impatient second Ctrl-C would leave the bag without its index: unreadable
            bag.close()
        return Recording(dict(bag.counts), stop.signalled, other_images, tuple(recorder.best_effort_topics))
