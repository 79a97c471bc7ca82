"""Procedural assets (bpy): the twin builder and the seven object classes. Twin YAMLs in twins/."""
