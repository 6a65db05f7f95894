import math

import pytest
from builtin_interfaces.msg import Time

from tactile_conversions.ros_time import TIME_LIMIT_S, is_ros_stamp, is_ros_time, seconds_to_time, time_to_seconds


def test_roundtrip_keeps_microseconds_at_epoch_scale():
    stamp = Time(sec=1_763_700_000, nanosec=123_456_000)
    back = seconds_to_time(time_to_seconds(stamp))
    assert back.sec == stamp.sec and abs(back.nanosec - stamp.nanosec) < 1000


def test_nanoseconds_carry_into_seconds():
    assert seconds_to_time(1.9999999999) == Time(sec=2, nanosec=0)


def test_negative_times_are_rejected():
    with pytest.raises(ValueError, match="cannot be negative"):
        seconds_to_time(-0.1)


def test_a_time_past_what_sec_can_hold_is_rejected_not_wrapped_round():
    """rclpy does not check sec's range: Time(sec=2**31) goes out as sec=-2**31."""
    latest = Time(sec=2**31 - 1, nanosec=999_999_000)
    assert seconds_to_time(time_to_seconds(latest)).sec == 2**31 - 1
    last_ns = time_to_seconds(Time(sec=2**31 - 1, nanosec=999_999_999))  # a float: 2**31 exactly
    assert not is_ros_time(last_ns)
    for seconds in (last_ns, TIME_LIMIT_S, 1e12, 1e300, math.inf, math.nan):  # 1e300: OverflowError before (review)
        with pytest.raises(ValueError, match="must be a finite number below 2\\*\\*31 s"):
            seconds_to_time(seconds)


@pytest.mark.parametrize("seconds, expected", [(0.0, True), (-4e-10, True), (1_763_700_000.5, True), (-1e-9, False),
                                               (-5.0, False), (2.0**31, False), (math.nan, False), (1e300, False),
                                               (-1e300, False)])
def test_is_ros_time_is_what_seconds_to_time_takes(seconds, expected):
    """-4e-10 s rounds to 0 ns, as seconds_to_time rounds it."""
    assert is_ros_time(seconds) == expected


@pytest.mark.parametrize("sec, nanosec, expected", [(0, 0, True), (1_763_700_000, 999_999_999, True),
                                                     (2**31 - 1, 999_999_999, True), (-1, 0, False),
                                                     (-1, 1_500_000_000, False), (5, 1_000_000_000, False)])
def test_a_stamp_republished_as_it_is_must_be_a_time_of_its_own_range(sec, nanosec, expected):
    """sec -1 with nanosec 1.5e9 is 0.5 s as seconds, which is_ros_time takes, and a negative stamp where a node sends
    it on as it came (review)."""
    assert is_ros_stamp(Time(sec=sec, nanosec=nanosec)) == expected
