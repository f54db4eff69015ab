"""A robot's own objects without shared ids: the tracker that names detections and the loop
closure that recognises a revisited group of objects."""
