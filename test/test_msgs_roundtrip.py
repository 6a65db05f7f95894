"""System test: ForceDistribution and ImageBundle cross real DDS between two separate processes unchanged."""

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

pytestmark = pytest.mark.system

PEERS = Path(__file__).parent / "ros_peers"
sys.path.insert(0, str(PEERS))

from sample_messages import force_distribution, image_bundle, to_plain  # noqa: E402


@pytest.fixture(scope="module")
def received():
    env = dict(os.environ, PYTHONPATH=f"{PEERS}{os.pathsep}{os.environ.get('PYTHONPATH', '')}",
               ROS_DOMAIN_ID=str(100 + os.getpid() % 100), ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST")
    talker = subprocess.Popen([sys.executable, str(PEERS / "talker.py")], env=env,
                              stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    try:
        listener = subprocess.run([sys.executable, str(PEERS / "listener.py")], env=env,
                                  capture_output=True, text=True, timeout=60)
    finally:
        talker.terminate()
        try:
            talker.wait(timeout=10)
        except subprocess.TimeoutExpired:  # Fast DDS can deadlock deleting the participant (docs/nodes.md): the
            talker.kill()                  # messages were received all the same; leave no process behind
            talker.wait()
    assert listener.returncode == 0, f"listener got no messages:\n{listener.stderr}"
    return json.loads(listener.stdout.strip().splitlines()[-1])


def test_force_distribution_roundtrips_every_field(received):
    sent = to_plain(force_distribution())
    got = received["force_distribution"]
    assert got.keys() == sent.keys()
    for field in sent:
        assert got[field] == sent[field], field
    assert len(got["forces_n"]) == 26 * 25 * 3


def test_image_bundle_roundtrips_every_field(received):
    sent = to_plain(image_bundle())
    got = received["image_bundle"]
    assert got.keys() == sent.keys()
    for field in sent:
        assert got[field] == sent[field], field
    assert [len(image["data"]) for image in got["images"]] == [128 * 128] * 4
