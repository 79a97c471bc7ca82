"""`blendgen import FORMAT SRC DST` and `blendgen import --check DST`.

The importers (`recording.importers`) read; what the frame analysis measures at import is
passed to them from here: comma2k19's camera yaw in the car from its preview frame.
"""

from __future__ import annotations

import argparse
import sys

from blendgen.errors import UserError

# per-format options: argparse dest -> importer keyword
_OPTIONS = {
    "video": ["imu_csv", "gnss_csv", "calib", "hfov_deg", "time_offset", "time_unit"],
    "images": ["calib", "hfov_deg", "labels", "label_format", "class_map"],
    "euroc": ["cam"],
    "kitti": ["kitti_cam"],
    "comma2k19": ["gnss_source"],
    "gopro": ["hfov_deg", "lens", "eis"],
    "rosbag": ["image_topic", "imu_topic", "gnss_topic", "speed_topic", "hfov_deg"],
}


class _DefaultsFormatter(argparse.HelpFormatter):
    """Shows an option's default only when it has one (no "(default: None)")."""

    def _get_help_string(self, action):
        h = action.help or ""
        if action.option_strings and action.default not in (None, False, argparse.SUPPRESS):
            h += " (default: %(default)s)"
        return h


def register(subparsers) -> None:
    from blendgen.recording.importers import FORMATS

    p = subparsers.add_parser(
        "import", help="convert a recording (video, EuRoC, KITTI raw, comma2k19, GoPro, ROS bag) into a "
                       "blendgen recording folder, then check it",
        description="Convert FORMAT's SRC into the recording folder DST (DESIGN.md) and print a check of "
                    "what is missing or odd. `blendgen import --check DST` checks an existing folder.",
        formatter_class=_DefaultsFormatter)
    p.add_argument("format", nargs="?", choices=list(FORMATS), help="source format")
    p.add_argument("src", nargs="?", help="source file or folder")
    p.add_argument("dst", nargs="?", help="recording folder to write")
    p.add_argument("--check", metavar="DST", help="only check an existing recording folder")
    p.add_argument("--force", action="store_true", help="write into a non-empty DST")
    p.add_argument("--no-progress", action="store_true", help="no progress bars")
    g = p.add_argument_group("video")
    g.add_argument("--imu", dest="imu_csv", help="IMU CSV: t, wx, wy, wz, ax, ay, az (rad/s, m/s^2)")
    g.add_argument("--gnss", dest="gnss_csv", help="GNSS CSV: t, lat, lon, alt[, heading_deg][, h_std_m]")
    g.add_argument("--calib", help="calib.yaml (blendgen format) with the camera intrinsics")
    g.add_argument("--time-offset", type=float, default=0.0,
                   help="seconds added to video timestamps to reach the CSVs' clock")
    g.add_argument("--time-unit", default="s", choices=["s", "ms", "us", "ns"], help="unit of the CSVs' t")
    g.add_argument("--hfov", dest="hfov_deg", type=float,
                   help="horizontal field of view (deg) when no calibration is known (video, gopro, rosbag)")
    g = p.add_argument_group("images: your own labels")
    g.add_argument("--labels", help="box labels of the images: a COCO JSON file, or a YOLO / KITTI label folder "
                                    "(<image name>.txt), matched to the images by file name")
    g.add_argument("--label-format", choices=["coco", "yolo", "kitti"], help="format of --labels")
    g.add_argument("--class-map", action="append", metavar="NAME=CLASS",
                   help="what a label class is: a blendgen class, `ignore` (an ignore region) or `drop`; "
                        "repeat or comma-separate; `*=drop` for every other name")
    g = p.add_argument_group("gopro")
    g.add_argument("--lens", help="the GoPro's lens mode (wide, linear, narrow, ...; the file does not say "
                                  "it): its calibrated fisheye from Gyroflow's lens database")
    g.add_argument("--eis", action="store_true", default=None,
                   help="with --lens: the video was electronically stabilised (EIS / HyperSmooth)")
    g = p.add_argument_group("euroc / kitti / comma2k19 / rosbag")
    g.add_argument("--cam", default="cam0", help="EuRoC camera folder")
    g.add_argument("--kitti-cam", type=int, default=2, help="KITTI camera number (image_0X)")
    g.add_argument("--gnss-source", default="ublox", choices=["ublox", "qcom"], help="comma2k19 GNSS log")
    g.add_argument("--image-topic")
    g.add_argument("--imu-topic")
    g.add_argument("--gnss-topic")
    g.add_argument("--speed-topic", help="rosbag: the vehicle's speed (Odometry or TwistStamped; picked by type "
                                         "when the bag has only one)")
    p.set_defaults(func=run)


def run(args) -> int:
    from blendgen.recording.importers import check_recording, format_findings, import_recording

    if args.check:
        if args.format or args.src or args.dst:
            raise UserError("use either `blendgen import --check DST` or `blendgen import FORMAT SRC DST`")
        findings = check_recording(args.check)
        print(format_findings(findings))
        return 2 if any(f.level == "error" for f in findings) else 0
    if not (args.format and args.src and args.dst):
        raise UserError("usage: blendgen import FORMAT SRC DST  (or blendgen import --check DST)")
    opts = {}
    for dest in _OPTIONS[args.format]:
        val = getattr(args, dest)
        if val is not None:
            opts["cam" if dest == "kitti_cam" else dest] = val
    if args.format == "comma2k19":
        from blendgen.analysis.lane_direction import still_camera_yaw

        opts["camera_yaw"] = still_camera_yaw
    dst = import_recording(args.format, args.src, args.dst, force=args.force,
                           show_progress=not args.no_progress, **opts)
    print(f"wrote {dst}", file=sys.stderr)
    findings = check_recording(dst)
    print(format_findings(findings))
    return 2 if any(f.level == "error" for f in findings) else 0
