"""Replay a bag: every message republished as recorded (serialized bytes, never deserialized) with the bag's
timing, scaled by `rate`, on publishers of the recorded types and the stack's QoS (tactile_bag.topics).

Messages keep their recorded header stamps: the bundle and fusion nodes work on capture stamps, so they
process a replay as they processed the live stream (no /clock is published).
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from pathlib import Path

import rclpy
from rclpy.node import Node

from tactile_bag.bagfile import BagError, BagReader
from tactile_bag.message_types import MessageTypeError, message_class
from tactile_bag.topics import absolute_topic, qos_profile
from tactile_conversions.stop_signals import until_stop_signal
from tactile_description.value_checks import is_number

#: The slowest replay, in times the recorded speed: a 25 ms frame period becomes 25 s. Slower would stretch a gap of
#: the bag's to where waiting it out is pointless (at 1e-300, beyond what time.sleep takes: OverflowError).
MIN_RATE = 1e-3

#: The longest single sleep while waiting for a message's time: a SIGTERM, which shuts rclpy down without waking the
#: sleep, stops the replay within it, and a wait beyond what one time.sleep takes (about 292 years: a gap of 106
#: days in the bag at MIN_RATE) is slept in pieces instead of raising OverflowError.
MAX_SLEEP_S = 0.25

#: How often a looped bag starts over whose topics have no period (s, at rate 1): one message each, or several received
#: at one time. Without a pause such a bag was published as fast as the CPU went (160000 times in 3 s; reviews).
SINGLE_MESSAGE_LOOP_S = 1.0


def play(path: str | Path, rate: float = 1.0, loop: bool = False, topics: Sequence[str] | None = None,
         wait_subscribers_s: float = 1.0) -> dict[str, int]:
    """Publish the bag's messages (or those of `topics`); returns messages published per topic.

    wait_subscribers_s: the longest wait between creating the publishers and the first message, for subscribers
    to discover them (a message published before a subscriber has matched is lost to it); playback starts
    sooner once every replayed topic has a matched subscriber.
    rclpy must be initialised by the caller. Ctrl-C stops the replay.
    """
    if not (is_number(rate) and rate >= MIN_RATE):
        raise ValueError(f"--rate must be a finite number >= {MIN_RATE:g}, got {rate!r}")
    if not (is_number(wait_subscribers_s) and wait_subscribers_s >= 0):
        raise ValueError(f"--wait-subscribers must be a finite number >= 0 s, got {wait_subscribers_s!r}")
    with BagReader(path) as bag:
        selected = bag.require_topics([absolute_topic(t) for t in topics]) if topics else sorted(bag.topics)
        if not sum(bag.counts[t] for t in selected):
            raise BagError(f"bag {bag.path} holds no messages on {selected}: nothing to play")
        bag.check_definitions(selected)  # before any publisher appears on the graph
        node = Node("tactile_bag_player")
        try:
            try:
                publishers = {t: node.create_publisher(message_class(bag.topics[t]), t, qos_profile(bag.topics[t]))
                              for t in selected}
            except MessageTypeError as exc:
                raise BagError(f"bag {bag.path}: cannot replay: {exc}") from exc
            counts = dict.fromkeys(selected, 0)
            with until_stop_signal():
                wait_until = time.monotonic() + wait_subscribers_s
                while time.monotonic() < wait_until and not all(p.get_subscription_count()
                                                                for p in publishers.values()):
                    time.sleep(0.02)
                while _play_once(bag, selected, publishers, counts, rate, loop) and loop:
                    pass
            return counts
        finally:
            node.destroy_node()


def _play_once(bag: BagReader, topics: list[str], publishers: dict, counts: dict[str, int], rate: float,
               loop: bool) -> bool:
    """One pass over the bag: message i goes out (t_i - t_0) / rate after the pass started. With `loop` the pass lasts
    one period more than its messages span (`_loop_period_ns`), so that the next pass's first messages follow the last
    ones as they followed each other (back to back before).

    Returns False when ROS was shut down meanwhile (SIGTERM), True at the end of the bag.
    """
    start_wall = time.monotonic()
    first_ns = None
    seen: dict[str, list[int]] = {}  # topic -> [first, last receive time ns, messages]
    for topic, _, time_ns, raw in bag.messages(topics):
        if first_ns is None:
            first_ns = time_ns
        if not _wait_until(start_wall + (time_ns - first_ns) * 1e-9 / rate):
            return False
        publishers[topic].publish(raw)
        counts[topic] += 1
        times = seen.setdefault(topic, [time_ns, time_ns, 0])
        times[1], times[2] = time_ns, times[2] + 1
    if loop and first_ns is not None:
        span_ns = max(last for _, last, _ in seen.values()) - first_ns
        return _wait_until(start_wall + (span_ns + _loop_period_ns(seen)) * 1e-9 / rate)
    return True


def _loop_period_ns(seen: dict[str, list[int]]) -> float:
    """The pause between two passes of a loop: the median over the topics of the mean time between their messages, or
    SINGLE_MESSAGE_LOOP_S where no topic has two messages at different times."""
    periods = sorted((last - first) / (n - 1) for first, last, n in seen.values() if last > first)
    return periods[len(periods) // 2] if periods else SINGLE_MESSAGE_LOOP_S * 1e9


def _wait_until(due: float) -> bool:
    """Sleep until time.monotonic() reaches `due`, in pieces of MAX_SLEEP_S; False if ROS was shut down meanwhile."""
    while rclpy.ok() and (delay := due - time.monotonic()) > 0:
        time.sleep(min(delay, MAX_SLEEP_S))
    return rclpy.ok()
