"""Camera side of the tactile sensor: from a capture frame to the image the model sees."""
