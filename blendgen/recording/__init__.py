"""Recordings: the one folder model of DESIGN.md, its reader/writer, importers, the synthetic demo."""

from blendgen.recording.model import ImuNoise, Recording  # noqa: F401
