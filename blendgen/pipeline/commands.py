"""CLI commands of the whole pipeline: run, validate, status."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from blendgen.errors import UserError
from blendgen.job.schema import load_job

FRAMES_FAILED_EXIT = 3  # the run went to the end, but some frames failed (listed with reasons)


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("run", help="run a job: sync -> plan -> render -> post -> labels",
                       description="Run the whole pipeline of a job. Finished frames are never redone: "
                                   "running the same job again resumes.")
    p.add_argument("job", type=Path, help="job YAML")
    p.add_argument("--engine", choices=["local", "ray"], help="override farm.engine")
    p.add_argument("--workers", type=int, help="override farm.workers")
    p.add_argument("--chunk", type=int, help="override farm.chunk (frames per task)")
    p.add_argument("--address", help="Ray cluster address (auto or HOST:PORT)")
    p.add_argument("--quiet", action="store_true", help="no progress output")
    p.set_defaults(func=cmd_run)

    p = sub.add_parser("validate", help="check a job and its recording without doing any work",
                       description="Check a job file (every field, the files it names) and the recording "
                                   "it uses, as `blendgen import --check` does: calib, CSV headers, "
                                   "monotonic times, physical ranges, and that every image decodes at the "
                                   "calibrated size. Renders nothing. Exit code 2 when something is wrong.")
    p.add_argument("job", type=Path, help="job YAML")
    p.set_defaults(func=cmd_validate)

    p = sub.add_parser("status", help="what is done, running, failed and left in a job folder",
                       description="Read a job folder's ledger (also while the job runs): per stage, the "
                                   "frames done, running, failed and left, the rate and ETA, and each "
                                   "failed frame or task with its reason and log.")
    p.add_argument("out", type=Path, help="the job's output folder")
    p.set_defaults(func=cmd_status)


def cmd_run(args) -> int:
    from blendgen.pipeline.run import Runner, print_summary

    for name in ("workers", "chunk"):
        v = getattr(args, name)
        if v is not None and v < 1:
            raise UserError(f"--{name} must be at least 1, got {v}")
    job = load_job(args.job)
    _warn_gpu_kernels(job, args.engine)
    runner = Runner(job, engine=args.engine, workers=args.workers, chunk=args.chunk,
                    address=args.address, progress=not args.quiet)
    summary = runner.run()
    print_summary(summary)
    return FRAMES_FAILED_EXIT if summary["frames"]["failed"] else 0


def _warn_gpu_kernels(job, engine: str | None = None) -> None:
    """A GPU job rendered here on a GPU that bpy ships no Cycles kernel for: the first render
    would sit for minutes compiling one (docs/render.md "On a GPU"); say so before it starts."""
    if job.render.device != "GPU" or (engine or job.farm.engine) != "local":
        return
    from blendgen.render.gpu_kernels import missing_archs

    for arch in missing_archs():
        print(f"blendgen: warning: bpy has no Cycles kernel for this GPU ({arch}): its first render compiles "
              "one from PTX (over 5 min on an H200, then cached by the driver); `blendgen gpu-kernels` "
              "builds it once ahead", file=sys.stderr)


def cmd_validate(args) -> int:
    job = load_job(args.job)
    _warn_gpu_kernels(job)
    findings = []
    if job.recording is not None:
        # the recording is checked before the job is called valid: its errors decide the verdict
        from blendgen.recording.importers import check_recording, format_findings

        findings = check_recording(job.recording_dir)
        errors = [str(f.message) for f in findings if f.level == "error"]
        if errors:
            print(format_findings(findings))
            raise UserError(f"the recording {job.recording_dir} has {len(errors)} problem(s):\n  "
                            + "\n  ".join(errors), where=str(args.job))
    src = f"recording {job.recording_dir}" if job.recording is not None else \
        f"synthetic {job.synthetic.duration_s:g} s at {job.synthetic.fps:g} fps"
    scene = f"twin {job.twin_path}" if job.twin_path else "ground-plane twin"
    print(f"{args.job}: valid job {job.name!r} (content hash {job.content_hash()})")
    print(f"  input:  {src}; {scene}")
    print(f"  output: {job.out_dir}")
    if job.inject.assets:
        from collections import Counter

        from blendgen.job.assets import discover

        n = Counter(r.sidecar["class"] for r in discover(job.asset_sources))
        print(f"  assets: {sum(n.values())} ({', '.join(f'{c} {k}' for c, k in sorted(n.items()))}); "
              f"headers and sidecars checked, Blender measures them when the job runs")
    if findings:
        print(format_findings(findings))
    return 0


def cmd_status(args) -> int:
    from blendgen.pipeline.outputs import JobFolder

    folder = JobFolder(args.out)
    if not folder.resolved_job.exists():
        raise UserError("not a blendgen job folder (no job.resolved.yaml)", where=str(args.out))
    stages = ["sync", "analysis", "plan", "export"] if folder.stage_done("analysis") else ["sync", "plan", "export"]
    print(f"{args.out}: " + ", ".join(f"{s} {'done' if folder.stage_done(s) else 'not done'}" for s in stages))
    line = folder.progress_line()  # sync, which runs in the job's own process (the rest: the ledger)
    if line:
        print(line)
    from blendgen.farm.ledger import ledger_path
    from blendgen.farm.status import status_report

    if ledger_path(folder.root).exists():
        print(status_report(folder.root))
    elif not line:
        print("no frame has been rendered yet (no farm ledger)")
    return 0
