"""Live views of a robot's estimates for visualisation tools (the ``foxglove`` extra)."""
