"""`blendgen sync RECORDING --lut LUT.csv --out DIR`: camera poses for a recording folder."""

from __future__ import annotations

import argparse
from pathlib import Path


def register(subparsers) -> None:
    p = subparsers.add_parser(
        "sync", help="estimate the camera pose of every frame (LUT + KLT/ORB VO + IMU/GNSS EKF)",
        description="Estimate T_world_cam for every frame of RECORDING and write OUT/poses.csv and "
                    "OUT/poses.tum. Without --lut, positions are ENU about --georef or the first GNSS fix.")
    p.add_argument("recording", type=Path, help="recording folder (calib.yaml, frames.csv, imu.csv, gnss.csv)")
    p.add_argument("--lut", type=Path, default=None, help="LUT CSV lat,lon,alt,heading_deg,x,y,z,yaw_deg")
    p.add_argument("--out", type=Path, required=True, help="output folder")
    p.add_argument("--georef", type=float, nargs=3, metavar=("LAT", "LON", "ALT"), default=None,
                   help="ENU origin when there is no LUT (default: the first GNSS fix)")
    p.add_argument("--twin", type=Path, default=None,
                   help="twin YAML: its road surface holds the vehicle's height (road-height constraint; "
                        "calib.yaml vehicle.camera_height_m) and its georeference is the default --georef")
    p.add_argument("--orb-features", type=int, default=None, help="VO features per frame (default 1500)")
    p.add_argument("--vo-method", choices=("auto", "klt", "orb"), default=None,
                   help="VO front end: klt (track-then-detect), orb (detect + match) or auto (default: klt at >= 10 fps)")
    p.add_argument("--reanchor-every", type=float, default=None, metavar="S",
                   help="re-anchoring interval in seconds (0 disables; default 5)")
    p.add_argument("--no-imu", action="store_true", help="ignore imu.csv")
    p.add_argument("--no-vo", action="store_true", help="do not use visual odometry")
    p.add_argument("--no-gnss", action="store_true", help="ignore gnss.csv (and the LUT)")
    p.add_argument("--no-speed", action="store_true", help="ignore speed.csv (the vehicle's odometer)")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.set_defaults(func=_run)


def settings_from_args(args: argparse.Namespace):
    from pydantic import ValidationError

    from blendgen.errors import UserError
    from blendgen.job.schema import Sync

    kw: dict = {}
    if args.orb_features is not None:
        kw["orb_features"] = args.orb_features
    if getattr(args, "vo_method", None) is not None:
        kw["vo_method"] = args.vo_method
    if args.reanchor_every is not None:
        kw["reanchor_every_s"] = args.reanchor_every if args.reanchor_every > 0 else None
    kw["use_imu"], kw["use_vo"], kw["use_gnss"] = not args.no_imu, not args.no_vo, not args.no_gnss
    kw["use_speed"] = not getattr(args, "no_speed", False)
    try:
        return Sync(**kw)
    except ValidationError as e:
        err = e.errors()[0]
        flag = {"orb_features": "--orb-features", "reanchor_every_s": "--reanchor-every"}.get(
            str(err["loc"][0]), str(err["loc"][0]))
        raise UserError(f"{flag}: {err['msg']} (got {err.get('input')!r})") from None


def _run(args: argparse.Namespace) -> int:
    from blendgen.errors import UserError
    from blendgen.recording.folder import read_recording
    from blendgen.sync.pipeline import run_sync

    settings = settings_from_args(args)
    if args.lut is not None and not args.lut.is_file():
        raise UserError("LUT file not found", where=str(args.lut))
    rec = read_recording(args.recording)
    georef, road = (tuple(args.georef) if args.georef else None), None
    if args.twin is not None:
        from blendgen.twin.model import load_twin

        twin = load_twin(args.twin)
        georef = georef if georef is not None else twin.georef
        road = twin.ground_heights
    res = run_sync(rec, settings, args.out, lut_path=args.lut, georef=georef, progress=not args.quiet,
                   road_surface=road)
    s = res.summary
    vo = s.get("vo_status", {})
    good = sum(v for k, v in vo.items() if k in ("ok", "rotation", "stationary", "repeated"))
    upd = s.get("updates", {})
    print(f"sync: {len(res.poses)} poses -> {Path(args.out) / 'poses.csv'} in {s['seconds']:.1f} s "
          f"(VO {good}/{max(len(res.poses) - 1, 0)} pairs, GNSS {upd.get('gnss', 0)} used / "
          f"{s.get('rejected', {}).get('gnss', 0)} rejected, "
          + (f"odometer {upd.get('speed', 0)} used / {s.get('rejected', {}).get('speed', 0)} rejected, "
             if s.get("sensors", {}).get("speed") else "")
          + f"{len(s.get('reader_issues', []))} reader issues)")
    if "odometer_unused" in s:
        print("sync: " + s["odometer_unused"])
    if "vo_trust" in s:
        tr = s["vo_trust"]
        print(f"sync: VO trust: {tr['trusted']} (gated against the gyro: {tr['gyro_gated']}, frozen frames: "
              f"{tr['frozen']}, skipped frames: {tr['skipped']}; stabiliser detected: "
              f"{'yes' if tr['stabiliser_detected'] else 'no'})")
    if "camera_imu_time_offset" in s:
        from blendgen.sync.time_offset import describe as describe_offset

        print("sync: " + describe_offset(s["camera_imu_time_offset"]))
    if "rolling_shutter" in s:
        from blendgen.sync.readout import describe as describe_readout

        print("sync: " + describe_readout(s["rolling_shutter"]))
    from blendgen.sync.calibration import describe, road_vehicle

    if "calibration" in s:
        print("sync: " + describe(s["calibration"]))
    elif not road_vehicle(rec):
        print("sync: not a road vehicle (calib.yaml vehicle.road_vehicle: false): no no-sideslip, level or "
              "road-height constraints, no mount estimate")
    if s.get("road_height"):
        r = s["road_height"]
        print(f"sync: road height: {r['point']} {r['height_m']:.3f} +- {r['height_std_m']:.3f} m above the twin's road"
              f" ({'calib.yaml' if r['height_std_m'] == 0 else 'estimated from the fixes'}), "
              f"{s['updates'].get('road', 0)} used / {s['rejected'].get('road', 0)} rejected")
    return 0
