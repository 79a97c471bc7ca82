"""A long dashcam video through `blendgen run`'s farm pipeline: what the supervisor costs, how
many workers it can feed, and when the first frame is rendered.

    nice -n 5 .venv/bin/python benchmarks/bench_long_video.py [--frames 1000 5000 15000]
        [--workers 1 2] [--engines local ray] [--first-frame 15000] [--render-frames 6] [--write-doc]

Recording: Udacity's solidWhiteRight freeway video (221 frames, 25 fps, 960x540, MIT) looped
to 15,000 frames (10 min): frames.csv repeats the video's indices (t = i / 25, index = i mod 221),
so the video is not re-encoded; the ego motion sees a cut at each loop.
Job: freeway_video's settings (ground_plane auto, 3-4 objects, 8-35 m, sequences), every frame.

Rows (`--frames` x `--workers` x `--engines`): `Runner(job, until="plan")` in a subprocess, the
supervisor: frame analysis and planning of N frames on the farm, from an empty output folder.
Measured: wall time per stage (first task to last item, the stages overlap), the supervisor's
own CPU (everything not in a farm task: sync's fixed poses, the ledger, the scheduler, poses.csv
and plan.jsonl) and its peak RSS, the CPU of its worker processes (every descendant, sampled
each second; Ray's own processes included) and the load average before and after.
`--first-frame N`: the whole job (`blendgen run`, rendering at the job's settings) on N frames,
stopped with Ctrl-C once `--render-frames` frames are rendered: seconds from the command's
start to the first composite.png on disk, and each rendered frame's CPU from the manifest.
Writes benchmarks/results/long_video.json, .png and (--write-doc) docs/benchmarks/long_video.md.
"""

from __future__ import annotations

import argparse
import json
import os
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
sys.path.insert(0, str(ROOT))

VIDEO = Path(os.environ.get("BLENDGEN_SHARED_DATA", ROOT.parent / "shared" / "data")) / "real" / "udacity_solidWhiteRight.mp4"
WORK = HERE / "results" / "tmp" / "long_video"
RESULTS = HERE / "results" / "long_video.json"
N_REC = 15000
FPS = 25.0


def recording() -> Path:
    """The looped recording (imported once, frames.csv rewritten to N_REC frames)."""
    rec = WORK / "rec"
    if (rec / "frames.csv").is_file() and sum(1 for _ in open(rec / "frames.csv")) == N_REC + 1:
        return rec
    base = WORK / "rec_video"
    if not (base / "frames.csv").is_file():
        r = subprocess.run([sys.executable, "-m", "blendgen.cli", "import", "video", str(VIDEO), str(base),
                            "--hfov", "55", "--no-progress"], capture_output=True, text=True)
        if r.returncode:
            raise SystemExit(r.stderr)
    n_video = sum(1 for _ in open(base / "frames.csv")) - 1
    rec.mkdir(parents=True, exist_ok=True)
    (rec / "calib.yaml").write_text((base / "calib.yaml").read_text())
    video = rec / "video.mp4"
    if not video.exists():
        os.link(base / "video.mp4", video)
    with open(rec / "frames.csv", "w") as f:
        f.write("t,index\n")
        for i in range(N_REC):
            f.write(f"{i / FPS:.9f},{i % n_video}\n")
    return rec


OBJECTS = [1, 2]   # objects per frame (set by --objects)


def write_job(name: str, frames: int, workers: int, engine: str, render: dict | None = None) -> Path:
    import yaml

    folder = WORK / name
    folder.mkdir(parents=True, exist_ok=True)
    job = {"name": name, "seed": 3, "recording": str(recording()), "ground_plane": "auto",
           "frames": {"start": 0, "stop": frames, "step": 1},
           "inject": {"objects_per_frame": list(OBJECTS), "distance_m": [8, 35], "sequences": True,
                      "classes": {"car": 3, "truck": 1, "bus": 1, "person": 1, "motorcycle": 1, "bicycle": 1}},
           "render": render or {"resolution": [960, 540], "samples": 16, "denoise": True},
           "post": {"illumination": "auto", "color_transfer": "none", "shadows": True},
           "export": {"formats": ["coco"], "min_visible_px": 64},
           "farm": {"workers": workers, "engine": engine}, "output": str(folder / "out")}
    (folder / "job.yaml").write_text(yaml.safe_dump(job, sort_keys=False))
    return folder / "job.yaml"


class Descendants(threading.Thread):
    """CPU seconds of every process below this one (sampled: a process that lived less than a
    second between samples is missed), and this thread's own CPU (not the supervisor's)."""

    def __init__(self):
        super().__init__(daemon=True)
        import psutil

        self.me = psutil.Process()
        self.cpu: dict[int, float] = {}
        self.stop = threading.Event()
        self.own = 0.0

    def sample(self):
        for p in self.me.children(recursive=True):
            try:
                t = p.cpu_times()
                self.cpu[p.pid] = max(self.cpu.get(p.pid, 0.0), t.user + t.system)
            except Exception:
                pass

    def run(self):
        while not self.stop.wait(1.0):
            self.sample()
        self.sample()
        self.own = time.thread_time()


def row_main(job_path: str, out_json: str) -> None:
    """One row, in its own process: this process is the supervisor."""
    import resource

    from blendgen.job.schema import load_job
    from blendgen.pipeline.run import Runner

    mon = Descendants()
    mon.start()
    t0 = time.perf_counter()
    s = Runner(load_job(job_path), progress=False, until="plan").run()
    wall = time.perf_counter() - t0
    mon.stop.set()
    mon.join()
    ru = resource.getrusage(resource.RUSAGE_SELF)
    Path(out_json).write_text(json.dumps({
        "wall_s": wall, "supervisor_cpu_s": ru.ru_utime + ru.ru_stime - mon.own, "peak_rss_mb": ru.ru_maxrss / 1024,
        "workers_cpu_s": sum(mon.cpu.values()), "summary": s}))


def run_row(frames: int, workers: int, engine: str) -> dict:
    name = f"n{frames}_{engine}_w{workers}_o{OBJECTS[0]}{OBJECTS[1]}"
    job = write_job(name, frames, workers, engine)
    out = WORK / name / "out"
    if out.exists():
        import shutil

        shutil.rmtree(out)
    res = WORK / name / "row.json"
    load0 = os.getloadavg()
    t0 = time.perf_counter()
    r = subprocess.run([sys.executable, str(Path(__file__).resolve()), "--row", str(job), str(res)],
                       capture_output=True, text=True)
    if r.returncode:
        raise SystemExit(f"{name}: {r.stdout[-3000:]}\n{r.stderr[-3000:]}")
    d = json.loads(res.read_text())
    d.update(frames=frames, workers=workers, engine=engine, objects=list(OBJECTS), load_before=load0[0],
             load_after=os.getloadavg()[0], process_wall_s=time.perf_counter() - t0)
    st = d["summary"]["pipeline"]
    d["stages"] = {k: {"span_s": round(v["last_done_s"] - v["first_start_s"], 1) if v["first_start_s"] is not None
                       and v["last_done_s"] is not None else None, "items": v["total"]} for k, v in st.items()}
    d["analysis_plan_s"] = max(v["last_done_s"] or 0 for v in st.values())
    d["per_item_cpu"] = item_cpu(out)
    print(f"{name}: analysis+plan {d['analysis_plan_s']:.0f} s, supervisor {1000 * d['supervisor_cpu_s'] / frames:.2f} "
          f"ms CPU/frame, peak RSS {d['peak_rss_mb']:.0f} MB, workers {d['workers_cpu_s'] / frames:.3f} CPU-s/frame, "
          f"load {load0[0]:.1f} -> {d['load_after']:.1f}", flush=True)
    return d


def item_cpu(out: Path) -> dict:
    """Median and total CPU seconds per item, per stage, from the manifest's records."""
    import numpy as np

    per: dict[str, list[float]] = {}
    with open(out / "manifest.jsonl") as f:
        for line in f:
            rec = json.loads(line)
            if isinstance(rec.get("cpu_s"), (int, float)):
                per.setdefault(rec["stage"], []).append(float(rec["cpu_s"]))
    return {k: {"median": float(np.median(v)), "total": float(np.sum(v)), "n": len(v)} for k, v in per.items()}


def first_frame(frames: int, workers: int, engine: str, n_render: int) -> dict:
    """The whole job from the command line, stopped once `n_render` frames are rendered."""
    name = f"first_n{frames}_{engine}_w{workers}_o{OBJECTS[0]}{OBJECTS[1]}"
    job = write_job(name, frames, workers, engine)
    out = WORK / name / "out"
    if out.exists():
        import shutil

        shutil.rmtree(out)
    load0 = os.getloadavg()
    t0 = time.perf_counter()
    p = subprocess.Popen([sys.executable, "-m", "blendgen.cli", "run", str(job)], stdout=subprocess.PIPE,
                         stderr=subprocess.STDOUT, text=True, start_new_session=True)
    first = None
    log: list[str] = []
    reader = threading.Thread(target=lambda: log.extend(p.stdout), daemon=True)
    reader.start()
    while p.poll() is None:
        time.sleep(0.5)
        done = list((out / "frames").glob("*/composite.png")) if (out / "frames").is_dir() else []
        if done and first is None:
            first = time.perf_counter() - t0
        if len(done) >= n_render:
            break
    os.killpg(p.pid, signal.SIGINT)   # Ctrl-C: the supervisor stops its workers and the ledger stays resumable
    p.wait(timeout=120)
    renders = []
    with open(out / "manifest.jsonl") as f:
        for line in f:
            rec = json.loads(line)
            if rec.get("stage") == "frames" and "timings" in rec:
                renders.append(rec["timings"]["total"])
    d = {"frames": frames, "workers": workers, "engine": engine, "objects": list(OBJECTS), "first_frame_s": first,
         "rendered": len(renders),
         "render_s": renders, "load_before": load0[0], "load_after": os.getloadavg()[0], "log_tail": "".join(log[-15:])}
    print(f"{name}: first rendered frame after {first:.0f} s; {len(renders)} frames rendered "
          f"({', '.join(f'{x:.1f}' for x in renders)} s each); load {load0[0]:.1f} -> {d['load_after']:.1f}", flush=True)
    return d


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--row", nargs=2, help=argparse.SUPPRESS)
    ap.add_argument("--frames", type=int, nargs="*", default=[1000, 5000, 15000])
    ap.add_argument("--workers", type=int, nargs="*", default=[1, 2])
    ap.add_argument("--engines", nargs="*", default=["local", "ray"])
    ap.add_argument("--first-frame", type=int, nargs="*", default=[])
    ap.add_argument("--render-frames", type=int, default=6)
    ap.add_argument("--objects", type=int, nargs=2, default=OBJECTS,
                    help="objects per frame (the freeway job has 3 4; planning costs grow fast with it)")
    ap.add_argument("--tag", default="", help="appended to each row's key in the results")
    ap.add_argument("--write-doc", action="store_true")
    a = ap.parse_args(argv)
    if a.row:
        return row_main(*a.row)
    OBJECTS[:] = a.objects
    if not VIDEO.is_file():
        raise SystemExit(f"needs {VIDEO}")
    results = json.loads(RESULTS.read_text()) if RESULTS.exists() else {"rows": {}, "first": {}}
    for n in a.frames:
        for engine in a.engines:
            for w in a.workers:
                results["rows"][f"{n}/{engine}/{w}/o{a.objects[0]}{a.objects[1]}{a.tag}"] = run_row(n, w, engine)
                RESULTS.write_text(json.dumps(results, indent=1))
    for n in a.first_frame:
        results["first"][f"{n}/local/2/o{a.objects[0]}{a.objects[1]}{a.tag}"] = first_frame(n, 2, "local", a.render_frames)
        RESULTS.write_text(json.dumps(results, indent=1))
    if a.write_doc:
        from bench_long_video_doc import write_doc  # noqa: E402 - the table and the estimates

        write_doc(results)


if __name__ == "__main__":
    sys.exit(main())
