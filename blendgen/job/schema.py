"""Job schema (`job.yaml`).

Every user mistake becomes a UserError naming the field path and what was expected.
Relative paths are resolved against the job file's folder; a `twin` may also name a
built-in twin (`demo_town`, `highway`) from assets_procedural/twins.
"""

from __future__ import annotations

import hashlib
import json
import sys
import tempfile
from pathlib import Path
from typing import Annotated, Any, Literal

from pydantic import (BaseModel, BeforeValidator, ConfigDict, Field, ValidationError,
                      field_validator, model_validator)

from blendgen import CLASSES
from blendgen.errors import UserError
from blendgen.validation import error_lines, read_yaml_mapping

BUILTIN_TWINS_DIR = Path(__file__).resolve().parents[2] / "assets_procedural" / "twins"
SCENARIOS = ("jaywalker", "cut_in", "near_collision", "occluded_pedestrian", "cyclist_overtake")
EXPORT_FORMATS = ("coco", "yolo", "kitti")
MAX_OBJECTS = 100  # per frame; beyond this the planner cannot place them in any view

PosInt = Annotated[int, Field(gt=0)]
PosFloat = Annotated[float, Field(gt=0)]


def _yaml_bool(v: Any) -> Any:
    """YAML reads an unquoted on/off/yes/no as a boolean: take it as the word it was."""
    return {True: "on", False: "off"}.get(v, v) if isinstance(v, bool) else v


OnOff = BeforeValidator(_yaml_bool)


class Section(BaseModel):
    model_config = ConfigDict(extra="forbid", validate_assignment=True, allow_inf_nan=False)


class Synthetic(Section):
    """A recording blendgen makes itself: a drive through the twin, rendered with Cycles,
    with IMU and GNSS simulated along the same trajectory."""

    duration_s: Annotated[float, Field(gt=0, le=600)] = 4.0
    fps: Annotated[float, Field(gt=0, le=60)] = 5.0
    resolution: tuple[PosInt, PosInt] = (480, 270)
    hfov_deg: Annotated[float, Field(gt=10, lt=170)] = 70.0
    camera_height_m: Annotated[float, Field(gt=0.2, le=5)] = 1.5
    speed_mps: Annotated[float, Field(ge=0, le=60)] = 8.0
    samples: Annotated[int, Field(ge=1, le=4096)] = 8
    imu_rate_hz: Annotated[float, Field(gt=0, le=2000)] = 200.0
    gnss_rate_hz: Annotated[float, Field(gt=0, le=100)] = 10.0
    gnss_noise_m: Annotated[float, Field(ge=0, le=50)] = 1.0
    start_time_utc: str = "2026-06-21T10:30:00Z"  # sets the sun for the synthetic recording


class Sync(Section):
    lut: Path | None = None  # default: the twin's exported LUT
    orb_features: Annotated[int, Field(ge=50, le=20000)] = 1500  # VO features per frame (KLT tracks or ORB keypoints)
    # klt: track-then-detect (>= 60 fps at 960x540); orb: detect + match; auto: klt at >= 10 fps
    vo_method: Literal["auto", "klt", "orb"] = "auto"
    reanchor_every_s: Annotated[float, Field(gt=0)] | None = 5.0  # None disables re-anchoring
    use_imu: bool = True
    use_gnss: bool = True
    use_vo: bool = True
    # the vehicle's odometer (recording speed.csv), with the IMU and GNSS of a road vehicle
    use_speed: bool = True
    gnss_std_m: PosFloat | None = None  # default: gnss.csv h_std_m, else 1.5 m
    smooth: bool = True  # Rauch-Tung-Striebel pass after the filter (uses later data for earlier poses)
    pose_rate_hz: Annotated[float, Field(gt=0, le=200)] = 10.0  # output rate when the recording has no frames
    vo_speed_mps: Annotated[float, Field(gt=0)] = 10.0  # assumed speed for the scale of VO-only runs (no IMU, no GNSS)
    road_vehicle: bool = True  # vehicle-frame constraints + mount/latency/lever-arm estimation; false for drones, handheld


class AssetSource(BaseModel):
    """An `inject.assets` entry with sidecar fields given in the job (checked when the assets
    are discovered, blendgen.job.assets.Sidecar): they apply to every asset under `path`
    and override the sidecars beside the files, key by key."""

    model_config = ConfigDict(extra="allow")

    path: Path

    @property
    def fields(self) -> dict[str, Any]:
        return dict(self.model_extra or {})


class Inject(Section):
    objects_per_frame: tuple[Annotated[int, Field(ge=0, le=MAX_OBJECTS)],
                             Annotated[int, Field(ge=0, le=MAX_OBJECTS)]] = (2, 6)
    classes: dict[str, Annotated[float, Field(ge=0)]] = Field(
        default_factory=lambda: {"car": 3.0, "person": 2.0, "bicycle": 1.0})
    scenarios: list[str] = Field(default_factory=list)
    distance_m: tuple[PosFloat, PosFloat] = (4.0, 40.0)
    min_projected_px: Annotated[int, Field(ge=1)] = 24
    sequences: bool = True  # objects keep identity and move along their path across frames
    # User asset libraries (docs/assets.md): folders or files of glTF/GLB, .blend, OBJ, FBX, USD
    # with sidecars; for a class the library has, `asset_share` of its objects come from it.
    # An entry is a path, or {path: ..., <sidecar fields>} (class, front, unit_m, ...) for
    # assets as they come, without sidecars beside them.
    assets: list[Path | AssetSource] = Field(default_factory=list)
    # one share for every class, or one per class ({car: 1, bus: 0}: classes not named take 1)
    asset_share: Annotated[float, Field(ge=0, le=1)] | dict[str, Annotated[float, Field(ge=0, le=1)]] = 1.0

    @field_validator("classes")
    @classmethod
    def _known_classes(cls, v: dict[str, float]) -> dict[str, float]:
        unknown = [k for k in v if k not in CLASSES]
        if unknown:
            raise ValueError(f"unknown class {unknown[0]!r}; expected one of {sorted(CLASSES)}")
        if sum(v.values()) <= 0:
            raise ValueError(f"expected at least one class with a positive weight, e.g. {{car: 1}}; "
                             f"classes: {sorted(CLASSES)}")
        return v

    @field_validator("asset_share")
    @classmethod
    def _share_classes(cls, v):
        if isinstance(v, dict):
            unknown = [k for k in v if k not in CLASSES]
            if unknown:
                raise ValueError(f"unknown class {unknown[0]!r}; expected one of {sorted(CLASSES)}")
        return v

    @field_validator("scenarios")
    @classmethod
    def _known_scenarios(cls, v: list[str]) -> list[str]:
        for s in v:
            if s not in SCENARIOS:
                raise ValueError(f"unknown scenario {s!r}; expected one of {list(SCENARIOS)}")
        return v

    @model_validator(mode="after")
    def _ranges(self):
        lo, hi = self.objects_per_frame
        if lo > hi:
            raise ValueError(f"objects_per_frame: min {lo} is greater than max {hi}")
        if self.distance_m[0] >= self.distance_m[1]:
            raise ValueError(f"distance_m: near {self.distance_m[0]} must be less than far {self.distance_m[1]}")
        return self


class Render(Section):
    resolution: tuple[PosInt, PosInt] | None = None  # default: the recording's camera resolution
    samples: Annotated[int, Field(ge=1, le=4096)] = 16  # + OIDN: 37 dB at ~3 s per 1280x720 frame (docs/render.md)
    denoise: bool = True
    adaptive_threshold: Annotated[float, Field(ge=0, le=1)] = 0.02
    max_bounces: Annotated[int, Field(ge=0, le=64)] = 4
    region: bool = True  # render only the projected bounds of objects and their shadows
    motion_blur: Annotated[Literal["auto", "on", "off"], OnOff] = "auto"
    # exposure for motion blur; auto: by the frame's light (render.effects.shutter_for)
    shutter_s: Annotated[float, Field(ge=0, le=1)] | Literal["auto"] = "auto"
    device: Literal["CPU", "GPU"] = "CPU"
    # what glass and clear coat mirror by day: the real frame around the camera
    # (render.environment) or the lighting estimate's uniform sky
    reflections: Literal["frame", "sky"] = "frame"
    threads: Annotated[int, Field(ge=0)] = 0  # 0: all cores of the worker


class Post(Section):
    illumination: Annotated[Literal["auto", "off"], OnOff] = "auto"
    color_transfer: Literal["reinhard", "mkl", "histogram", "none"] = "none"  # measured: no transfer helps YOLOX recall on real photos (docs/benchmarks/realism.md)
    shadows: bool = True
    sensor_match: bool = True
    relight: bool = True  # re-weight the EXR lighting passes toward the estimate
    # How far colour transfer moves an object toward its background's statistics (0..1);
    # None: 0.1 after environment-light matching, 0.3 without (docs/post.md, measured).
    color_strength: Annotated[float, Field(ge=0, le=1)] | None = None


class Export(Section):
    formats: list[Literal["coco", "yolo", "kitti"]] = Field(default_factory=lambda: list(EXPORT_FORMATS))
    min_visible_px: Annotated[int, Field(ge=0)] = 64
    small_objects: Literal["drop", "ignore"] = "drop"
    save_exr: bool = True
    kitti_types: Literal["kitti", "extended"] = "kitti"  # docs/labels.md: KITTI's own types, or one per class
    yolo_val_fraction: Annotated[float, Field(ge=0, le=0.9)] = 0.0  # share of frames in YOLO's val split (seeded)


class Labels(Section):
    """The real road users already in the background frames (docs/labels.md).

    user: the recording's own labels (labels.json, `blendgen import images --labels`), updated
    for what injected objects cover; detector: the frame analysis' detections, labels at or
    above `detector_score` and ignore regions below; ignore: every real road user an ignore
    region; none: unlabelled (background to a trainer). auto: user when the recording has
    labels, none for a synthetic recording, detector otherwise."""

    real: Literal["auto", "user", "detector", "ignore", "none"] = "auto"
    # None: labels.real_objects.DETECTOR_LABEL_SCORE, measured in docs/benchmarks/real_labels.md
    detector_score: Annotated[float, Field(gt=0, le=1)] | None = None


class Farm(Section):
    engine: Literal["local", "ray"] = "local"
    workers: Annotated[int, Field(ge=1, le=256)] = 1
    chunk: Annotated[int, Field(ge=1)] = 4
    max_attempts: Annotated[int, Field(ge=1, le=20)] = 3
    recycle_after_frames: Annotated[int, Field(ge=1)] = 200
    max_rss_mb: Annotated[int, Field(ge=256)] = 6000
    # a local worker that finishes no item for this long is killed and its task retried; "auto":
    # 30 min or 10x the run's slowest item; null: never
    item_timeout_s: Annotated[float, Field(gt=0)] | Literal["auto"] | None = "auto"
    address: str | None = None  # Ray: "auto" or HOST:PORT


class Frames(Section):
    start: Annotated[int, Field(ge=0)] = 0
    stop: Annotated[int, Field(ge=0)] | None = None
    step: Annotated[int, Field(ge=1)] = 1


_GROUND_PLANE_RANGES = {"camera_height_m": (0.2, 5.0, "0.2 < h <= 5 m"), "pitch_deg": (-45.0, 45.0, "-45..45 deg"),
                        "roll_deg": (-30.0, 30.0, "-30..30 deg")}


class GroundPlane(Section):
    """A number fixes a value; "auto" estimates it from the frames (blendgen.analysis.camera).
    `ground_plane: auto` sets all three of height, pitch and roll to "auto"."""

    camera_height_m: float | Literal["auto"] = 1.5
    pitch_deg: float | Literal["auto"] = 0.0
    roll_deg: float | Literal["auto"] = 0.0
    lane_width_m: Annotated[float, Field(gt=1, le=6)] = 3.5
    # Analyse every background frame (real road users, road, hood) and keep objects clear of
    # them; false: the fixed pose with no analysis (the behaviour before issue 12).
    analysis: bool = True
    detector: Path | None = None  # a YOLOX-format COCO ONNX model; default: the bundled YOLOX-Nano
    # Where traffic comes towards the camera: "auto" beyond a yellow centre line found in the
    # frame (North American markings), "left" beyond the ego lane's left edge (two-way roads
    # with white centre lines), "none" nowhere (one-way streets, divided highways).
    oncoming: Literal["auto", "left", "none"] = "auto"
    # Stills of a recording: one camera ("shared": one mount and one hood for all) or each image
    # from a camera of its own ("per_image": photos of different cars, e.g. a dataset's frames).
    stills: Literal["shared", "per_image"] = "shared"

    @field_validator("camera_height_m", "pitch_deg", "roll_deg", mode="before")
    @classmethod
    def _number_or_auto(cls, v, info):
        lo, hi, what = _GROUND_PLANE_RANGES[info.field_name]
        if isinstance(v, str) and v.strip().lower() == "auto":
            return "auto"
        if isinstance(v, bool) or not isinstance(v, (int, float)):
            raise ValueError(f"expected a number ({what}) or `auto`")
        if not (lo < v <= hi if info.field_name == "camera_height_m" else lo <= v <= hi):
            raise ValueError(f"expected {what} or `auto`")
        return float(v)

    @property
    def auto(self) -> list[str]:
        """The fields to estimate."""
        return [k for k in ("camera_height_m", "pitch_deg", "roll_deg") if getattr(self, k) == "auto"]


class Job(Section):
    name: Annotated[str, Field(min_length=1, max_length=100, pattern=r"^[A-Za-z0-9_.-]+$")]
    seed: Annotated[int, Field(ge=0, strict=True)] = 0  # strict: `seed: true` is not 1
    recording: Path | None = None
    synthetic: Synthetic | None = None
    twin: str | None = None  # built-in twin name, path to a twin YAML or a map (.xodr, .osm, .osm.pbf)
    ground_plane: GroundPlane | None = None  # for footage without a twin
    frames: Frames = Field(default_factory=Frames)
    sync: Sync = Field(default_factory=Sync)
    inject: Inject = Field(default_factory=Inject)
    render: Render = Field(default_factory=Render)
    post: Post = Field(default_factory=Post)
    export: Export = Field(default_factory=Export)
    labels: Labels = Field(default_factory=Labels)
    farm: Farm = Field(default_factory=Farm)
    output: Path

    # Set by load_job, not by the user.
    job_dir: Path | None = Field(default=None, exclude=True)

    @field_validator("ground_plane", mode="before")
    @classmethod
    def _ground_plane_auto(cls, v):
        if isinstance(v, str):
            if v.strip().lower() != "auto":
                raise ValueError("expected `auto` or a block (camera_height_m, pitch_deg, roll_deg, "
                                 "lane_width_m)")
            return {"camera_height_m": "auto", "pitch_deg": "auto", "roll_deg": "auto"}
        return v

    @model_validator(mode="after")
    def _sources(self):
        if (self.recording is None) == (self.synthetic is None):
            raise ValueError("give exactly one of `recording` (a folder) or `synthetic` (a block)")
        if (self.twin is None) == (self.ground_plane is None):
            raise ValueError("give exactly one of `twin` (built-in name or YAML path) or `ground_plane` (a block)")
        if self.synthetic is not None and self.twin is None:
            raise ValueError("`synthetic` renders a drive through a twin: give `twin` too")
        if self.synthetic is not None and self.labels.real == "user":
            raise ValueError("labels.real: user needs a real recording with labels; a synthetic recording has "
                             "no real road users")
        if self.frames.stop is not None and self.frames.stop <= self.frames.start:
            raise ValueError(f"frames.stop ({self.frames.stop}) must be greater than frames.start")
        return self

    # ---- derived paths
    def path(self, p: Path | str) -> Path:
        p = Path(p).expanduser()
        return (p if p.is_absolute() else (self.job_dir or Path.cwd()) / p).resolve()

    @property
    def out_dir(self) -> Path:
        return self.path(self.output)

    @property
    def recording_dir(self) -> Path:
        return self.path(self.recording) if self.recording is not None else self.out_dir / "recording"

    @property
    def twin_path(self) -> Path | None:
        if self.twin is None:
            return None
        builtin = BUILTIN_TWINS_DIR / f"{self.twin}.yaml"
        return builtin if "/" not in self.twin and not self.twin.endswith((".yaml", ".yml", ".xodr", ".osm", ".pbf")) else self.path(self.twin)

    def resolved(self) -> dict[str, Any]:
        """The job with defaults filled in, paths absolute, as plain data."""
        d = self.model_dump(mode="json")
        d["output"] = str(self.out_dir)
        if self.recording is not None:
            d["recording"] = str(self.recording_dir)
        if self.twin is not None:
            d["twin"] = str(self.twin_path)
        if self.sync.lut is not None:
            d["sync"]["lut"] = str(self.path(self.sync.lut))
        d["inject"]["assets"] = [str(p) if not f else {"path": str(p), **f} for p, f in self.asset_sources]
        if self.ground_plane is not None and self.ground_plane.detector is not None:
            d["ground_plane"]["detector"] = str(self.path(self.ground_plane.detector))
        return d

    @property
    def asset_sources(self) -> list[tuple[Path, dict[str, Any]]]:
        """`inject.assets` as (absolute path, sidecar fields given in the job)."""
        return [(self.path(a.path), a.fields) if isinstance(a, AssetSource) else (self.path(a), {})
                for a in self.inject.assets]

    def content_hash(self) -> str:
        """Hash of everything that changes results; `farm` (how work is spread) is left out
        so that a resumed run may use other workers."""
        d = self.resolved()
        d.pop("farm", None)
        blob = json.dumps(d, sort_keys=True).encode()
        return hashlib.sha256(blob).hexdigest()[:16]


def parse_job(data: Any, *, source: str = "job", job_dir: Path | None = None) -> Job:
    if not isinstance(data, dict):
        raise UserError(f"expected a mapping of job fields at the top level, got {type(data).__name__}", where=source)
    try:
        job = Job.model_validate(data)
    except ValidationError as e:
        lines = error_lines(e, " (check the spelling; see README 'Job format')")
        raise UserError("invalid job:\n  " + "\n  ".join(lines), where=source) from None
    job.job_dir = job_dir
    _check_files(job, source)
    return job


def _check_files(job: Job, source: str) -> None:
    if job.recording is not None and not job.recording_dir.is_dir():
        raise UserError(f"recording: folder {job.recording_dir} does not exist", where=source)
    _check_output(job.out_dir, source)
    if job.render.device == "GPU" and job.farm.engine == "local" and not _has_gpu():
        raise UserError("render.device: GPU, but this machine shows no GPU device (/dev/nvidia*, /dev/dri, "
                        "/dev/kfd); use CPU", where=source)
    tp = job.twin_path
    if tp is not None and not tp.is_file():
        names = sorted(p.stem for p in BUILTIN_TWINS_DIR.glob("*.yaml"))
        raise UserError(f"twin: {job.twin!r} is neither a built-in twin {names} nor an existing YAML or map file "
                        f"({tp})", where=source)
    gp = job.ground_plane
    if gp is not None and gp.detector is not None:
        det = job.path(gp.detector)
        if not det.is_file() or det.suffix.lower() != ".onnx":
            raise UserError(f"ground_plane.detector: expected an existing .onnx file, got {det}", where=source)
    if job.labels.real == "user" and job.recording is not None and not (job.recording_dir / "labels.json").is_file():
        raise UserError(f"labels.real: user, but the recording {job.recording_dir} has no labels.json; import "
                        "them with `blendgen import images DIR REC --labels PATH --label-format coco|yolo|kitti`, "
                        "or use labels.real: detector", where=source)
    if job.sync.lut is not None and not job.path(job.sync.lut).is_file():
        raise UserError(f"sync.lut: file {job.path(job.sync.lut)} does not exist", where=source)
    if job.inject.assets:  # sidecars and file headers, without Blender (docs/assets.md)
        from blendgen.job.assets import discover

        discover(job.asset_sources)


def _check_output(out: Path, source: str) -> None:
    """`output` must be a folder we can create and write: refuse a file or a read-only place."""
    p = out
    while not p.exists() and p != p.parent:
        p = p.parent
    if not p.is_dir():
        raise UserError(f"output: {p} is a file, expected a folder (or a path to create one)", where=source)
    try:  # a real probe: os.access says yes to root even on read-only or virtual filesystems
        tempfile.TemporaryFile(dir=p).close()
    except OSError as e:
        raise UserError(f"output: cannot write in {p} ({e.strerror}); choose another folder",
                        where=source) from None


def _has_gpu() -> bool:
    return any(Path(p).exists() for p in ("/dev/nvidia0", "/dev/dri", "/dev/kfd")) or sys.platform == "darwin"


def load_job(path: str | Path) -> Job:
    path = Path(path)
    data = read_yaml_mapping(path, "job")
    return parse_job(data, source=str(path), job_dir=path.resolve().parent)
