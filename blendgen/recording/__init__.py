"""Recordings: the one folder model of DESIGN.md, its reader/writer, frames by id, importers."""

from blendgen.recording.model import ImuNoise, Recording  # noqa: F401
