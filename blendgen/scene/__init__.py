"""Bpy-free scene side: placement on the twin and the per-frame plans."""
