import pytest
from builtin_interfaces.msg import Time

from tactile_conversions.ros_time import seconds_to_time, time_to_seconds


def test_roundtrip_keeps_microseconds_at_epoch_scale():
    stamp = Time(sec=1_763_700_000, nanosec=123_456_000)
    back = seconds_to_time(time_to_seconds(stamp))
    assert back.sec == stamp.sec and abs(back.nanosec - stamp.nanosec) < 1000


def test_nanoseconds_carry_into_seconds():
    assert seconds_to_time(1.9999999999) == Time(sec=2, nanosec=0)


def test_negative_times_are_rejected():
    with pytest.raises(ValueError, match="cannot be negative"):
        seconds_to_time(-0.1)
