"""CameraArrivals: a camera's silence on a clock that steps back (a looped bag) or does not run yet (no /clock)."""

from tactile_fusion.camera_arrivals import CameraArrivals

CAMERAS = ("cam0", "cam1", "cam2")
TIMEOUT_S = 0.25


def test_a_camera_is_live_for_the_timeout_after_its_last_images():
    arrivals = CameraArrivals(CAMERAS)
    assert arrivals.live(100.0, TIMEOUT_S) == ()
    arrivals.arrived(CAMERAS, 100.0)
    arrivals.arrived(["cam0", "cam2"], 100.2)
    assert arrivals.live(100.3, TIMEOUT_S) == ("cam0", "cam2")
    assert arrivals.live(100.5, TIMEOUT_S) == ()


def test_a_step_back_of_the_clock_keeps_a_silent_camera_silent():
    """A bag played with --loop starts its clock again: on the raw readings the camera silent since 1050 s was live
    again for the 52 s of the step, and the synchroniser waited for it (review)."""
    arrivals = CameraArrivals(CAMERAS)
    arrivals.arrived(CAMERAS, 1049.0)
    for k in range(41):
        arrivals.arrived(["cam0", "cam1"], 1050.0 + k * 0.05)  # cam2 silent for 2 s
    arrivals.arrived(["cam0", "cam1"], 1000.0)  # the loop starts again
    assert arrivals.live(1000.01, TIMEOUT_S) == ("cam0", "cam1")
    arrivals.arrived(["cam2"], 1000.05)  # and it comes back when it sends again
    assert arrivals.live(1000.06, TIMEOUT_S) == CAMERAS


def test_images_before_the_clock_runs_count_from_its_first_reading():
    """With use_sim_time the clock reads 0 until the first /clock: every camera was found silent when it came
    (review)."""
    arrivals = CameraArrivals(CAMERAS)
    arrivals.arrived(["cam0", "cam1"], 0.0)
    assert arrivals.live(0.0, TIMEOUT_S) == ("cam0", "cam1")
    assert arrivals.live(1000.0, TIMEOUT_S) == ("cam0", "cam1")  # dated at the first reading
    assert arrivals.live(1000.3, TIMEOUT_S) == ()


def test_a_clock_reset_to_zero_does_not_revive_a_camera_silent_for_long():
    """A simulation reset to 0 (paused, restarted) made every camera that ever sent live again (review)."""
    arrivals = CameraArrivals(CAMERAS)
    arrivals.arrived(CAMERAS, 100.0)
    arrivals.arrived(["cam0", "cam1"], 105.0)
    assert arrivals.live(105.1, TIMEOUT_S) == ("cam0", "cam1")
    assert arrivals.live(0.0, TIMEOUT_S) == ("cam0", "cam1")


def test_another_clock_keeps_each_cameras_age():
    """use_sim_time cleared while the bundle node runs: the steady clock's hours since boot after a bag's simulated
    seconds read as a step forward, and every camera was found silent at once (noticed in stop 41's review)."""
    arrivals = CameraArrivals(CAMERAS)
    arrivals.arrived(["cam2"], 99.9)
    arrivals.arrived(["cam0", "cam1"], 100.2)
    arrivals.clock_changed()
    assert arrivals.live(5000.0, TIMEOUT_S) == ("cam0", "cam1")  # ages 0 and 0.3 s at the old clock's 100.2 s
    assert arrivals.live(5000.2, TIMEOUT_S) == ("cam0", "cam1")
    assert arrivals.live(5000.3, TIMEOUT_S) == ()  # and they age on the new clock


def test_another_clock_that_does_not_run_yet_keeps_each_cameras_age_until_it_does():
    """use_sim_time set while the bundle node runs, before any /clock: the simulated clock reads 0 for a while, then
    starts at a bag's 1000 s, after the steady clock's 50 s since boot."""
    arrivals = CameraArrivals(CAMERAS)
    arrivals.arrived(["cam2"], 49.9)
    arrivals.arrived(["cam0", "cam1"], 50.2)
    arrivals.clock_changed()
    assert arrivals.live(0.0, TIMEOUT_S) == ("cam0", "cam1")  # as at the old clock's latest reading
    arrivals.arrived(["cam2"], 0.0)  # images while the new clock does not run date from its first reading
    assert arrivals.live(1000.0, TIMEOUT_S) == CAMERAS
    assert arrivals.live(1000.26, TIMEOUT_S) == ()  # cam0 and cam1 were 0 s old at the change, cam2 from 1000 s
