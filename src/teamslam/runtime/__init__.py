"""How robots talk: the transport seam and message types."""

from teamslam.runtime.transport import (
    CommonMarginalMessage,
    InProcessTransport,
    MapIdsMessage,
    Transport,
)

__all__ = ["CommonMarginalMessage", "InProcessTransport", "MapIdsMessage", "Transport"]
