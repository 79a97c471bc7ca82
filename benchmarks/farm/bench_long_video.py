"""A long dashcam video through `blendgen run`'s farm pipeline: what the supervisor costs, how
many workers it can feed, and when the first frame is rendered.

    nice -n 5 .venv/bin/python benchmarks/farm/bench_long_video.py [--frames 1000 5000 15000]
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

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))  # the checkout: its blendgen, benchmarks.common
from benchmarks import common  # noqa: E402
from benchmarks.common import REAL, TMP, blendgen_cmd  # noqa: E402
from benchmarks.common import RESULTS as RESULTS_DIR  # noqa: E402

VIDEO = REAL / "udacity_solidWhiteRight.mp4"
WORK = TMP / "long_video"
RESULTS = RESULTS_DIR / "long_video.json"
N_REC = 15000
FPS = 25.0


def recording() -> Path:
    """The looped recording (imported once, frames.csv rewritten to N_REC frames)."""
    rec = WORK / "rec"
    if (rec / "frames.csv").is_file() and sum(1 for _ in open(rec / "frames.csv")) == N_REC + 1:
        return rec
    base = WORK / "rec_video"
    if not (base / "frames.csv").is_file():
        r = subprocess.run(blendgen_cmd("import", "video", VIDEO, base, "--hfov", "55", "--no-progress"),
                           capture_output=True, text=True)
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
    p = subprocess.Popen(blendgen_cmd("run", job), stdout=subprocess.PIPE,
                         stderr=subprocess.STDOUT, text=True, start_new_session=True)
    first = None
    log: list[str] = []
    reader = threading.Thread(target=lambda: log.extend(p.stdout), daemon=True)
    reader.start()
    import psutil

    sup, rss = psutil.Process(p.pid), 0   # the supervisor's RSS once its task graph is built
    while p.poll() is None:
        time.sleep(0.5)
        try:
            rss = max(rss, sup.memory_info().rss)
        except psutil.Error:
            pass
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
         "rendered": len(renders), "supervisor_rss_mb": rss / 2**20,
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
        write_doc(results)


HOUR_FRAMES = int(3600 * FPS)


def write_doc(results: dict) -> None:
    """The table, the plot and the estimates (docs/benchmarks/long_video.md)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np

    rows = sorted(results["rows"].values(), key=lambda r: (r["objects"], r["frames"], r["engine"], r["workers"]))
    lines = ["# Long video benchmark: the farm pipeline's supervisor, workers and first frame", "",
             "Command: `nice -n 5 .venv/bin/python benchmarks/farm/bench_long_video.py --frames N --workers W --engines E "
             "--objects A B` (rows below), `--first-frame 15000` (first rendered frame), then `--write-doc`.",
             "Machine: 2 CPU cores shared with up to four other sessions (the 1-minute load average before and "
             "after each row is given: above 2 the cores were busy with other work, and wall times and the "
             "1 -> 2 worker ratio say more about the load than about blendgen; the CPU-second figures do not "
             "depend on it).", "",
             f"Recording: Udacity's solidWhiteRight freeway video (221 frames, 25 fps, 960x540, MIT) looped to "
             f"{N_REC:,} frames (10 min; frames.csv repeats the video's indices: not re-encoded, the ego motion sees a "
             "cut at each loop). Job: `jobs/freeway_video.yaml`'s settings (ground_plane auto, 8-35 m, sequences, "
             "cars, trucks, buses, persons, motorcycles, bicycles), every frame, objects per frame as in the table; "
             "analysis and plan only (`Runner(job, until=\"plan\")`), from an empty output folder.", "",
             "| frames | engine | workers | objects | analysis + plan wall (s) | analysis stages (s) | plan (s) | "
             "supervisor CPU (ms/frame) | supervisor peak RSS (MB) | workers CPU (s/frame): analysis / plan | "
             "load before -> after |", "|---:|---|---:|---|---:|---:|---:|---:|---:|---|---|"]
    for r in rows:
        st, pc = r["stages"], r["per_item_cpu"]
        an = [v["span_s"] for k, v in st.items() if k not in ("plan", "plan_file") and v["span_s"] is not None]
        a_cpu = sum(v["total"] for k, v in pc.items() if k not in ("plan", "plan_file")) / r["frames"]
        p_cpu = pc.get("plan", {"total": 0})["total"] / r["frames"]
        lines.append(f"| {r['frames']:,} | {r['engine']} | {r['workers']} | {r['objects'][0]}-{r['objects'][1]} | "
                     f"{r['analysis_plan_s']:.0f} | {max(an):.0f} | {st['plan']['span_s']:.0f} | "
                     f"{1000 * r['supervisor_cpu_s'] / r['frames']:.2f} | {r['peak_rss_mb']:.0f} | "
                     f"{a_cpu:.3f} / {p_cpu:.3f} | {r['load_before']:.1f} -> {r['load_after']:.1f} |")
    lines += ["", "Wall times are the pipeline's (first task to last item); a stage's span overlaps the others'. "
              "Supervisor CPU: the `blendgen run` process's own user + system CPU over the whole run (imports, "
              "sync's fixed poses, the ledger, the scheduler), divided by the job's frames. Workers' CPU: each "
              "item's process CPU from the manifest (`cpu_s`).", ""]
    by = {(r["frames"], r["engine"], r["workers"], tuple(r["objects"])): r for r in rows}
    ratio = []
    for (n, e, w, o), r in sorted(by.items()):
        one = by.get((n, e, 1, o))
        if w == 2 and one:
            ratio.append(f"{n:,} frames, {e}: 2 workers / 1 worker = {r['analysis_plan_s'] / one['analysis_plan_s']:.2f} "
                         f"(wall; load {one['load_before']:.1f} and {r['load_before']:.1f} at the starts)")
    if ratio:
        lines += ["Analysis + plan wall time, 2 workers against 1:", ""] + [f"- {x}" for x in ratio] + [""]
    loc = sorted((r for r in rows if r["engine"] == "local" and r["workers"] == 2), key=lambda r: r["frames"])
    if len(loc) >= 2:
        slope = (loc[-1]["peak_rss_mb"] - loc[0]["peak_rss_mb"]) * 2**20 / (loc[-1]["frames"] - loc[0]["frames"])
        lines += [f"Supervisor memory: {loc[0]['peak_rss_mb']:.0f} MB at {loc[0]['frames']:,} frames, "
                  f"{loc[-1]['peak_rss_mb']:.0f} MB at {loc[-1]['frames']:,}: {slope:.0f} bytes per frame (the "
                  "frame list, the scheduler's state, the ledger's page cache).", ""]
    for key, f in sorted(results.get("first", {}).items()):
        lines += [f"First rendered frame ({f['frames']:,}-frame job, `blendgen run` from the command line, "
                  f"{f['workers']} {f['engine']} workers, objects {f['objects'][0]}-{f['objects'][1]}, rendering at "
                  f"960x540, Cycles 16 spp + denoise, post with shadows): **{f['first_frame_s']:.0f} s** after the "
                  f"command started (load {f['load_before']:.1f} -> {f['load_after']:.1f}); {f['rendered']} frames "
                  f"rendered before Ctrl-C, {np.median(f['render_s']):.1f} s each (median, frame work in a worker)"
                  + (f"; the supervisor's peak RSS until then {f['supervisor_rss_mb']:.0f} MB (its whole task graph "
                     "and ledger built)" if f.get("supervisor_rss_mb") else "") + ".", ""]
    lines += estimates(rows, results.get("first", {}))
    fig, ax = plt.subplots(1, 2, figsize=(9, 3.2))
    for e in sorted({r["engine"] for r in rows}):
        for w in sorted({r["workers"] for r in rows}):
            rr = sorted((r for r in rows if r["engine"] == e and r["workers"] == w and r["objects"] == rows[0]["objects"]),
                        key=lambda r: r["frames"])
            if rr:
                x = [r["frames"] for r in rr]
                ax[0].plot(x, [1000 * r["supervisor_cpu_s"] / r["frames"] for r in rr], "o-", label=f"{e} x{w}")
                ax[1].plot(x, [r["peak_rss_mb"] for r in rr], "o-", label=f"{e} x{w}")
    ax[0].axhline(5, color="grey", ls="--", lw=0.8)
    ax[0].set(xscale="log", xlabel="frames", ylabel="supervisor CPU (ms / frame)")
    ax[1].set(xscale="log", xlabel="frames", ylabel="supervisor peak RSS (MB)")
    ax[0].legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(RESULTS_DIR / "long_video.png", dpi=100)
    lines += ["", "Plot: `benchmarks/results/long_video.png`.", ""]
    common.write_doc("long_video.md", "\n".join(lines))


def estimates(rows: list[dict], first: dict) -> list[str]:
    """An hour of video on a 16-core node and on 10 of them, from the measured CPU per frame."""
    import numpy as np

    if not rows:
        return []
    big = max(rows, key=lambda r: (r["frames"], r["workers"]))
    n = big["frames"]
    pc = big["per_item_cpu"]
    a_cpu = sum(v["total"] for k, v in pc.items() if k not in ("plan", "plan_file")) / n
    p_cpu = pc.get("plan", {"total": 0})["total"] / n
    sup = big["supervisor_cpu_s"] / n
    render = float(np.median([x for f in first.values() for x in f["render_s"]])) if first else None
    per_frame = a_cpu + p_cpu + (render or 0.0)
    out = ["## What an hour of video costs (an estimate from the measured CPU per frame)", "",
           f"From the {n:,}-frame {big['engine']} row with {big['workers']} workers (objects "
           f"{big['objects'][0]}-{big['objects'][1]}): analysis {a_cpu:.2f} CPU-s a frame, planning {p_cpu:.2f}"
           + (f", rendering + post + labels {render:.1f} s a frame (960x540, 16 spp, the first-frame run)" if render else "")
           + f"; the supervisor {1000 * sup:.2f} ms a frame. An hour of 25 fps video is {HOUR_FRAMES:,} frames.", "",
           f"- One supervisor keeps about **{per_frame / sup:,.0f} workers** busy (worker CPU per frame / supervisor CPU "
           "per frame; its lease heartbeats and the ledger's commits are batched, so this holds while each worker's "
           "tasks last longer than a few ms).",
           f"- Analysis + plan of an hour: {HOUR_FRAMES * (a_cpu + p_cpu) / 3600:.1f} CPU-hours: "
           f"{HOUR_FRAMES * (a_cpu + p_cpu) / 3600 / 16:.2f} h on a 16-core node, "
           f"{HOUR_FRAMES * (a_cpu + p_cpu) / 3600 / 160 * 60:.0f} min on 10 such nodes."]
    if render:
        tot = HOUR_FRAMES * per_frame / 3600
        out += [f"- Everything (analysis, plan, render at these settings): {tot:.0f} CPU-hours: {tot / 16:.1f} h on a "
                f"16-core node, {tot / 160:.1f} h on 10 nodes (renders on CPU; a GPU per node renders several times "
                "faster: docs/render.md)."]
    out += ["", "Serial parts besides the supervisor: the ego motion's chain (`poses`, "
            f"{1000 * pc.get('poses', {'median': 0})['median']:.1f} ms a frame: it keeps ahead of any number of "
            "workers below ~1/that frames per second) and the plan windows' two phases (an odd window waits for its "
            "neighbours)."]
    return out


if __name__ == "__main__":
    sys.exit(main())
