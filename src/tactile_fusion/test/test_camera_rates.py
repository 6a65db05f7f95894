"""camera_rates: each camera's frame period from its stamps, and whether the bundle node's settings fit it."""

import pytest

from tactile_fusion.approximate_sync import camera_sync_settings
from tactile_fusion.camera_rates import INTERVALS, CameraPeriods, SyncSettings, period_misfits


def defaults(frame_rate_hz: float, cameras: int = 4) -> SyncSettings:
    """The bundle node's default settings for a sensor description's frame rate."""
    sync = camera_sync_settings(frame_rate_hz)
    return SyncSettings(cameras, sync["max_spread_s"], sync["min_period_s"], 10 / frame_rate_hz)


def test_a_period_is_known_once_enough_intervals_are_recorded():
    periods = CameraPeriods()
    for k in range(INTERVALS):
        periods.add("cam0", 10.0 + 0.1 * k)
        assert periods.period_s("cam0") is None
    periods.add("cam0", 10.0 + 0.1 * INTERVALS)
    assert periods.period_s("cam0") == pytest.approx(0.1)
    assert periods.period_s("cam1") is None  # each camera its own


def test_a_lost_frame_does_not_move_the_period_and_stamps_going_back_start_the_record_over():
    periods = CameraPeriods()
    for stamp in (0.0, 0.025, 0.075, 0.1, 0.125):  # the frame at 0.05 lost
        periods.add("cam0", stamp)
    assert periods.period_s("cam0") == pytest.approx(0.025)
    periods.add("cam0", 0.05)  # a replay started over: no interval of -0.075 s
    assert periods.period_s("cam0") is None
    for k in range(1, INTERVALS + 1):
        periods.add("cam0", 0.05 + 0.5 * k)
    assert periods.period_s("cam0") == pytest.approx(0.5)


@pytest.mark.parametrize("period_s", [0.025, 0.023, 0.027, 0.0125, 0.033])
def test_cameras_near_the_descriptions_rate_fit_its_default_settings(period_s):
    assert period_misfits(period_s, defaults(40.0)) == []


def test_cameras_slower_than_the_description_are_told_what_goes_wrong():
    settings = defaults(40.0)  # max_spread 0.025 s, camera_timeout 0.25 s
    misfits = period_misfits(0.1, settings)  # 10 Hz: four free-running cameras up to 0.075 s apart
    assert len(misfits) == 1 and "up to 0.075 s apart" in misfits[0] and "too wide" in misfits[0]
    misfits = period_misfits(0.25, settings)
    assert len(misfits) == 2 and "left out of the bundles and back with every frame" in misfits[0]
    assert period_misfits(0.1, defaults(40.0, cameras=1)) == []  # one camera: nothing to spread


def test_cameras_faster_than_min_period_allows_are_told_and_settings_for_their_rate_fit():
    assert "sooner than min_period_s (0.0125 s)" in period_misfits(0.01, defaults(40.0))[0]
    assert period_misfits(0.01, defaults(100.0)) == []
    assert period_misfits(0.25, defaults(4.0)) == []
