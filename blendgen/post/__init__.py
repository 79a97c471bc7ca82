"""Post stage (bpy-free): illumination estimate, lighting-pass re-weighting, colour transfer,
sensor matching and compositing of rendered objects into real frames (docs/post.md)."""
