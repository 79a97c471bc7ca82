"""Render farm: a SQLite task ledger, a local worker pool by default, Ray for clusters.

The supervisor side (everything imported here) never imports bpy; workers do.
"""

from .books import FarmSummary
from .graph import Stage
from .processor import clean_stale_temps
from .run import run_pipeline, run_tasks
from .seeds import frame_seed

__all__ = ["FarmSummary", "Stage", "clean_stale_temps", "frame_seed", "run_pipeline", "run_tasks"]
