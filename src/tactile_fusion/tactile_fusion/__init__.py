"""Force-distribution learning and inference for the multi-camera tactile sensor (no ROS import in the core)."""
