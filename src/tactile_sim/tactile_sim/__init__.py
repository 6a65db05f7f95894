"""The simulated tactile sensor: contact mechanics, gel, particles, cameras and scene effects (no ROS import)."""
