"""Launch files and configuration of the tactile sensor graph (sources: top-level launch/ and config/)."""
