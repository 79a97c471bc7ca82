"""Bpy-free scene side: the twin model, placement and per-frame plans."""
