"""The topic names of the tactile graph (docs/nodes.md), in one place for the nodes, the tools and the tests."""

from __future__ import annotations

BUNDLE_TOPIC = "/tactile/image_bundle"
ESTIMATE_TOPIC = "/tactile/force_distribution"
GROUND_TRUTH_TOPIC = "/tactile/ground_truth/force_distribution"
#: Largest distance between an estimate's stamp and its ground truth's for the two to be compared (tactile-demo,
#: tactile-bag eval): the sensor's frames are 25 ms apart, and an estimate's stamp, its bundle's, is the median of
#: jittered camera stamps.
MATCH_TOLERANCE_S = 0.010
WRENCH_TOPIC = "/tactile/wrench"
MARKERS_TOPIC = "/tactile/force_markers"


def camera_topic(camera_id: str) -> str:
    """Where the camera `camera_id` publishes its images."""
    return f"/tactile/{camera_id}/image"


def camera_frame_id(camera_id: str) -> str:
    """The frame_id of the camera `camera_id`'s images (the real and the simulated cameras stamp the same)."""
    return f"{camera_id}_optical"
