"""Render driver. Only session.py (and what it imports) touches bpy; exr.py is bpy-free."""
