"""numpy <-> ROS messages of the tactile stack (images, times, force distributions), shared by the nodes."""
