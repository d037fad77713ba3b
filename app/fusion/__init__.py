"""Map fusion: many journeys' signs -> one map, journey-bias flags, and change detection.

Pure, deterministic functions with no database; the service calls them from a worker.
"""

from app.fusion.changes import detect_changes, frames_in_view
from app.fusion.config import FusionConfig
from app.fusion.fuse import fuse_map
from app.fusion.types import (FusionResult, JourneyBias, JourneyCoverage, JourneySign, MapSign)

__all__ = ["FusionConfig", "FusionResult", "JourneyBias", "JourneyCoverage", "JourneySign",
           "MapSign", "detect_changes", "frames_in_view", "fuse_map"]
