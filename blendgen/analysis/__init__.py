"""Frame analysis for footage without a map: camera, horizon, hood, road and real objects
from the frames themselves (bpy-free). See `model.py` for the per-frame contract."""
