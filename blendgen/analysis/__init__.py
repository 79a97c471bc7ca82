"""Frame analysis for footage without a map: camera, horizon, hood, road and real objects
from the frames themselves (bpy-free). `blendgen.frame_analysis` is the per-frame contract."""
