"""The twin YAML schema (see docs/twin_and_objects.md). Errors name the field path."""

from __future__ import annotations

from typing import Annotated, Literal

from pydantic import BaseModel, ConfigDict, Field, model_validator

Pos = Annotated[float, Field(gt=0)]
NonNeg = Annotated[float, Field(ge=0)]
XY = tuple[float, float]
RGB = tuple[Annotated[float, Field(ge=0, le=1)], Annotated[float, Field(ge=0, le=1)],
            Annotated[float, Field(ge=0, le=1)]]


class _M(BaseModel):
    model_config = ConfigDict(extra="forbid")


class Georef(_M):
    lat0: Annotated[float, Field(ge=-90, le=90)]
    lon0: Annotated[float, Field(ge=-180, le=180)]
    alt0: float = 0.0
    # A projected twin (maps georeferenced in e.g. UTM): twin x/y = projected x/y - origin;
    # GNSS lat/lon map through pyproj instead of ENU about (lat0, lon0).
    proj: str | None = None
    origin: XY = (0.0, 0.0)


class Arc(_M):
    radius_m: Annotated[float, Field(ge=5)]
    angle_deg: Annotated[float, Field(ge=-180, le=180)]  # > 0 turns left


class Segment(_M):
    straight: Pos | None = None
    arc: Arc | None = None

    @model_validator(mode="after")
    def _one(self):
        if (self.straight is None) == (self.arc is None):
            raise ValueError("give exactly one of `straight: LENGTH_M` or `arc: {radius_m, angle_deg}`")
        return self


class Road(_M):
    id: Annotated[str, Field(min_length=1)]
    # The centre-line: either explicit points, or a start pose and straight/arc segments.
    points: list[XY] | None = None
    start: XY | None = None
    heading_deg: float = 0.0  # yaw of the start tangent, CCW from +x
    segments: list[Segment] | None = None
    lanes_forward: Annotated[int, Field(ge=0, le=6)] = 1  # along the centre-line, right of it
    lanes_backward: Annotated[int, Field(ge=0, le=6)] = 1
    lane_width_m: Annotated[float, Field(ge=2.0, le=6.0)] = 3.5
    shoulder_m: NonNeg = 0.3
    median_m: NonNeg = 0.0
    median_barrier: bool = False
    sidewalk_m: NonNeg = 0.0
    curb_height_m: Annotated[float, Field(ge=0, le=0.4)] = 0.15
    center_line: Literal["solid", "dashed", "double", "none"] = "dashed"
    speed_mps: Annotated[float, Field(gt=0, le=45)] = 12.0
    junction: str | None = None  # id of the junction this connecting road belongs to (maps)
    # Relief and varying widths (maps), one value per `points` entry: the centre-line's
    # surface height (m), the cross-section's roll (superelevation, deg, > 0 falls to the
    # right) and each lane's width (m; inner lane first).
    z: list[float] | None = None
    superelevation_deg: list[Annotated[float, Field(ge=-30, le=30)]] | None = None
    lane_widths_forward: list[list[NonNeg]] | None = None
    lane_widths_backward: list[list[NonNeg]] | None = None

    @model_validator(mode="after")
    def _line(self):
        if self.points is not None:
            if self.segments is not None:
                raise ValueError("give either `points` or `start` + `segments`, not both")
            if len(self.points) < 2:
                raise ValueError("`points` needs at least two [x, y] points")
        elif self.start is None or not self.segments:
            raise ValueError("give the centre-line as `points` or as `start` + `segments`")
        if self.lanes_forward + self.lanes_backward == 0:
            raise ValueError("a road needs at least one lane (lanes_forward + lanes_backward > 0)")
        for name in ("z", "superelevation_deg", "lane_widths_forward", "lane_widths_backward"):
            v = getattr(self, name)
            if v is None:
                continue
            if self.points is None or len(v) != len(self.points):
                raise ValueError(f"`{name}` needs `points` and one entry per point "
                                 f"({len(v)} entries, {len(self.points or [])} points)")
            n = {"lane_widths_forward": self.lanes_forward, "lane_widths_backward": self.lanes_backward}.get(name)
            if n is not None and any(len(w) != n for w in v):
                raise ValueError(f"`{name}`: every entry lists {n} lane width(s)")
        return self


class Intersection(_M):
    id: str
    center: XY
    crosswalks: bool = True
    stop_lines: bool = True
    signals: bool = True  # slots where the planner may place traffic lights


class Crosswalk(_M):
    road: str
    s_m: NonNeg
    width_m: Annotated[float, Field(gt=0.5, le=10)] = 3.0


class Building(_M):
    center: XY
    size: tuple[Pos, Pos]
    yaw_deg: float = 0.0
    height_m: Annotated[float, Field(gt=2, le=300)] = 12.0
    floors: Annotated[int, Field(ge=1, le=80)] | None = None
    facade: RGB = (0.62, 0.55, 0.48)


class Pole(_M):
    position: XY
    height_m: Annotated[float, Field(gt=0.5, le=30)] = 7.0
    kind: Literal["street_lamp", "utility"] = "street_lamp"
    yaw_deg: float = 0.0


class Sign(_M):
    position: XY
    yaw_deg: float = 0.0  # direction the sign face points
    kind: Literal["stop", "yield", "speed", "info"] = "speed"
    height_m: Annotated[float, Field(gt=0.5, le=8)] = 2.4


class TrafficLightStatic(_M):
    position: XY
    yaw_deg: float = 0.0  # direction the lamps face
    state: Literal["red", "amber", "green"] = "red"
    mount_height_m: Annotated[float, Field(gt=1.5, le=8)] = 2.6


class Barrier(_M):
    start: XY
    end: XY
    kind: Literal["jersey", "guardrail"] = "jersey"
    height_m: Annotated[float, Field(gt=0.2, le=3)] = 0.8


class Tree(_M):
    position: XY
    height_m: Annotated[float, Field(gt=1, le=40)] = 7.0


class MaterialSpec(_M):
    color: RGB | None = None
    roughness: Annotated[float, Field(ge=0, le=1)] | None = None
    wear: Annotated[float, Field(ge=0, le=1)] | None = None


class TwinSpec(_M):
    name: str
    georef: Georef
    roads: Annotated[list[Road], Field(min_length=1)]
    intersections: list[Intersection] = Field(default_factory=list)
    crosswalks: list[Crosswalk] = Field(default_factory=list)
    buildings: list[Building] = Field(default_factory=list)
    poles: list[Pole] = Field(default_factory=list)
    signs: list[Sign] = Field(default_factory=list)
    traffic_lights: list[TrafficLightStatic] = Field(default_factory=list)
    barriers: list[Barrier] = Field(default_factory=list)
    trees: list[Tree] = Field(default_factory=list)
    ground_m: Annotated[float, Field(ge=10, le=20000)] = 400.0  # side of the square ground plane (at least the roads' extent + 40 m)
    materials: dict[Literal["asphalt", "marking", "sidewalk", "curb", "ground", "building"],
                    MaterialSpec] = Field(default_factory=dict)

    @model_validator(mode="after")
    def _refs(self):
        ids = [r.id for r in self.roads]
        dup = {i for i in ids if ids.count(i) > 1}
        if dup:
            raise ValueError(f"duplicate road id {sorted(dup)[0]!r}")
        for i, c in enumerate(self.crosswalks):
            if c.road not in ids:
                raise ValueError(f"crosswalks[{i}].road: unknown road {c.road!r}; roads are {ids}")
        return self
