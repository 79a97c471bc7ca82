"""The report a person looks at after a job: OUT/report/index.md (bpy-free)."""

from blendgen.report.build import build_report

__all__ = ["build_report"]
