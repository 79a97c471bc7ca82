"""The Ray engine (`engine="ray"`, extra `blendgen[ray]`): tasks on a Ray cluster, the same
ledger as source of truth.

The driver (this process, holding the ledger lock) submits one Ray task per ledger task.
Inside the Ray worker process the processor is built once and cached (a warm Blender
session), tasks run on the worker's main thread, and `max_calls` restarts the process after
`recycle_after` items' worth of tasks to bound memory. Crashes of a worker process or a whole
node are retried by Ray (`max_retries`); failures raised by the processor come back to the
driver, which re-submits them to another node and retires nodes that keep failing.
"""

from __future__ import annotations

import atexit
import collections
import contextlib
import json
import math
import os
import signal
import socket

from ..errors import StageError, UserError
from .books import Books
from .local import AUTO_TIMEOUT_FACTOR, AUTO_TIMEOUT_FLOOR_S, worker_env
from .processor import close_processor, load_processor, redirect_output, rss_mb, run_items

NODE_MAX_FAILURES_IN_ROW = 3
TOKEN_ENV = ("RAY_AUTH_TOKEN", "RAY_AUTH_TOKEN_PATH")  # Ray's own token settings
LOOPBACK = "127.0.0.1"
# Ray's switch for "not a multi-host cluster": with it off, a private Ray binds every server
# (GCS, raylet, workers, agents) to loopback instead of all interfaces (measured with psutil,
# tests/test_farm.py::test_local_ray_listens_on_loopback_only).
_CLUSTER_ENV = "RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER"


@contextlib.contextmanager
def _loopback_only():
    """While a private Ray starts: this process and the servers it spawns use loopback."""
    from ray._private import ray_constants

    old_env, old_flag = os.environ.get(_CLUSTER_ENV), ray_constants.ENABLE_RAY_CLUSTER
    os.environ[_CLUSTER_ENV] = "0"
    ray_constants.ENABLE_RAY_CLUSTER = False
    try:
        yield
    finally:
        ray_constants.ENABLE_RAY_CLUSTER = old_flag
        if old_env is None:
            os.environ.pop(_CLUSTER_ENV, None)
        else:
            os.environ[_CLUSTER_ENV] = old_env

_CACHE: dict[tuple[str, str], object] = {}  # per Ray worker process: the warm processor


@contextlib.contextmanager
def _item_alarm(item_timeout_s):
    """`arm(slowest_item_s)`: the process ends unless another item finishes within the limit
    (farm.item_timeout_s; "auto": 30 min or 10x this task's slowest item). SIGALRM at its
    default action ends the process in the kernel, whatever Python or C code hangs; Ray then
    retries the task elsewhere. Signals need the main thread, where Ray runs tasks."""
    if item_timeout_s is None:
        yield lambda slowest: None
        return

    def arm(slowest: float) -> None:
        limit = item_timeout_s if item_timeout_s != "auto" else max(AUTO_TIMEOUT_FLOOR_S,
                                                                     AUTO_TIMEOUT_FACTOR * slowest)
        signal.alarm(max(1, math.ceil(limit)))

    old = signal.signal(signal.SIGALRM, signal.SIG_DFL)
    try:
        yield arm
    finally:
        signal.alarm(0)
        signal.signal(signal.SIGALRM, old)


def ray_task(processor: str, processor_args: dict, items: list[str], log_path: str,
             item_timeout_s: float | str | None = None) -> dict:
    """Body of one Ray task (runs in a Ray worker process, on its main thread)."""
    import ray

    key = (processor, json.dumps(processor_args, sort_keys=True))
    events: list[dict] = []
    ctx = ray.get_runtime_context()
    where = {"node": ctx.get_node_id(), "worker": f"{socket.gethostname()}/ray-{os.getpid()}"}
    with redirect_output(log_path):
        print(f"[blendgen.farm] ray worker {where['worker']} node {where['node'][:12]}: "
              f"{len(items)} items", flush=True)
        proc = _CACHE.get(key)
        if proc is None:
            try:
                proc = load_processor(processor, processor_args)
            except Exception as e:
                import traceback

                traceback.print_exc()
                return {"ok": False, "events": [{"ev": "error", "item": items[0] if items else "",
                                                 "error": f"init: {type(e).__name__}: {e}"}],
                        **where}
            _CACHE[key] = proc
            atexit.register(close_processor, proc)  # best effort when max_calls ends us
        if item_timeout_s is not None:
            print(f"[blendgen.farm] farm.item_timeout_s {item_timeout_s}: this process ends (SIGALRM) when "
                  "an item runs that long", flush=True)
        slowest = [0.0]
        with _item_alarm(item_timeout_s) as arm:
            def emit(ev: dict) -> None:
                events.append(ev)
                slowest[0] = max(slowest[0], ev.get("process_s", 0.0))
                arm(slowest[0])

            arm(0.0)
            ok = run_items(proc, items, emit)
    return {"ok": ok, "events": events, "rss_mb": rss_mb(), **where}


class RayEngine:
    def __init__(self, books: Books, *, workers: int, recycle_after: int, address: str | None,
                 item_timeout_s: float | str | None = "auto"):
        self.books = books
        self.graph = books.graph
        self.item_timeout_s = item_timeout_s
        self.processor = " + ".join(sorted({s.processor for s in books.stages.values()}))
        self.workers, self.recycle_after, self.address = workers, recycle_after, address
        self.any_ok = False
        self.init_failures = 0
        self.node_fails: collections.Counter = collections.Counter()
        self.banned: set[str] = set()
        self._rr = 0

    def run(self) -> None:
        try:
            import ray
        except ImportError:
            raise UserError("needs Ray: pip install 'blendgen[ray]'", where="farm.engine=ray")
        started_here = not ray.is_initialized()
        if started_here:
            self._init(ray)
        try:
            self._loop(ray)
        finally:
            if started_here:
                ray.shutdown()

    def _init(self, ray) -> None:
        # Ray workers start from the raylet, never from this process: bpy cannot leak into
        # them; PYTHONPATH makes blendgen (and the processor's module) importable there.
        env = worker_env(self.books.tmp_dir)
        kw = dict(runtime_env={"env_vars": {k: env[k] for k in ("PYTHONPATH", "TMPDIR")}},
                  logging_level="WARNING", log_to_driver=False)
        try:
            if self.address:
                if not any(os.environ.get(k) for k in TOKEN_ENV):
                    raise UserError(
                        "a Ray cluster run needs the cluster's authentication token: set "
                        "RAY_AUTH_TOKEN (the token) or RAY_AUTH_TOKEN_PATH (a file holding it); "
                        "see docs/farm.md 'Ray cluster'", where="farm.address")
                os.environ["RAY_AUTH_MODE"] = "token"  # never talk to a cluster without it
                ray.init(address=self.address, **kw)
            else:  # a private single-machine Ray, gone when the job ends
                with _loopback_only():
                    ray.init(num_cpus=self.workers, include_dashboard=False,
                             _node_ip_address=LOOPBACK, **kw)
        except (ConnectionError, RuntimeError, ValueError) as e:
            raise UserError(f"cannot connect to the Ray cluster at {self.address!r}: {e}",
                            where="farm.address") from e

    def _remote(self, ray, stage) -> object:
        """The Ray function of a stage: a stage that renders (`recycle`) asks for the GPU and
        ends its process after `recycle_after` items' worth of tasks (Blender's memory); the
        others (frame analysis, planning) need one CPU and no GPU."""
        gpus_here = ray.cluster_resources().get("GPU", 0) > 0
        num_gpus = float(os.environ.get("BLENDGEN_RAY_NUM_GPUS", 1 if gpus_here else 0)) if stage.recycle else 0
        num_cpus = float(os.environ.get("BLENDGEN_RAY_NUM_CPUS", 1)) if stage.recycle else 1
        # max_calls counts tasks; recycle_after counts items
        return ray.remote(num_cpus=num_cpus, num_gpus=num_gpus,
                          max_calls=max(1, math.ceil(self.recycle_after / stage.chunk)) if stage.recycle else 0,
                          max_retries=max(0, self.books.max_attempts - 1),
                          retry_exceptions=False)(ray_task)

    def _healthy_nodes(self, ray) -> list[str]:
        return [n["NodeID"] for n in ray.nodes()
                if n["Alive"] and n["Resources"].get("CPU", 0) > 0 and n["NodeID"] not in self.banned]

    def _options(self, ray, tid: int) -> dict:
        """Default placement; a retry, or any task once a node is retired, is pinned (softly)
        to a healthy node it has not failed on."""
        avoid = {a[5:] for a in self.books.ledger.avoid(tid) if a.startswith("node:")}
        if not avoid and not self.banned:
            return {}
        from ray.util.scheduling_strategies import NodeAffinitySchedulingStrategy

        nodes = self._healthy_nodes(ray)
        pick = [n for n in nodes if n not in avoid] or nodes
        if not pick:
            return {}
        self._rr += 1
        return {"scheduling_strategy": NodeAffinitySchedulingStrategy(
            pick[self._rr % len(pick)], soft=True)}

    def _loop(self, ray) -> None:
        fns = {name: self._remote(ray, st) for name, st in self.books.stages.items()}
        specs = self.books.processors()
        cpus = int(ray.cluster_resources().get("CPU", self.workers))
        cap = 2 * max(self.workers, cpus)  # enough queued for every slot, few to re-place
        pending: collections.deque[int] = collections.deque()  # retries, before any ready task
        inflight: dict = {}
        try:
            while True:
                self.books.fail_blocked()
                while (pending or self.graph.n_ready) and len(inflight) < cap:
                    tid = pending.popleft() if pending else self.graph.pop()
                    attempt, items, log = self.books.claim(tid, "ray")
                    if not items:
                        self.books.on_task_done(tid)
                        continue
                    stage = self.books.stage_of(tid)
                    ref = fns[stage].options(**self._options(ray, tid)).remote(
                        specs[stage]["processor"], specs[stage]["processor_args"], items, log, self.item_timeout_s)
                    inflight[ref] = (tid, attempt)
                self.books.flush(force=False)
                if not inflight:
                    if pending or self.graph.n_ready:
                        continue
                    if self.graph.waiting:
                        raise StageError(f"farm: {self.graph.waiting} task(s) wait for items no task will "
                                         "finish (a pipeline's dependencies are wrong)")
                    break
                ready, _ = ray.wait(list(inflight), num_returns=1, timeout=1.0)
                for ref in ready:
                    tid, attempt = inflight.pop(ref)
                    if not self._collect(ray, ref, tid, attempt):
                        pending.appendleft(tid)
                self.books.flush(force=False)
        except BaseException:
            for ref, (tid, _) in inflight.items():
                with contextlib.suppress(Exception):
                    ray.cancel(ref, force=True)
                self.books.release(tid)
            with contextlib.suppress(Exception):
                self.books.flush()
            raise

    def _collect(self, ray, ref, tid: int, attempt: int) -> bool:
        """Record a finished Ray task. Returns False when it must be re-submitted."""
        try:
            res = ray.get(ref)
        except ray.exceptions.RayError as e:  # worker/node lost beyond Ray's own retries
            msg = f"{type(e).__name__}: {str(e).splitlines()[0][:500]}"
            return self.books.on_task_failed(tid, "ray:unknown", msg)
        node = f"node:{res['node']}"
        self.books.ledger.set_attempt_worker(tid, attempt, res["worker"])
        error = None
        for ev in res["events"]:
            if ev["ev"] == "item":
                self.books.on_item(tid, attempt, res["worker"], ev)
            elif ev["ev"] == "item_failed":
                self.books.on_item_failed(tid, res["worker"], ev)
            elif ev["ev"] == "error":
                error = f"item {ev['item']}: {ev['error']} (on {res['worker']})"
        if res["ok"]:
            self.books.on_task_done(tid)
            self.node_fails[node] = 0
            self.any_ok = True
            return True
        if error and ": init: " in error:
            self.init_failures += 1
            if not self.any_ok and self.init_failures >= NODE_MAX_FAILURES_IN_ROW:
                self.books.on_task_failed(tid, node, error)
                raise StageError(f"farm stage {self.books.stage}: processor {self.processor} "
                                 f"failed to start on the Ray workers: {error} "
                                 f"(log: {self.books.ledger.task(tid)['log_path']})")
        final = self.books.on_task_failed(tid, node, error or "unknown error")
        self.node_fails[node] += 1
        if self.node_fails[node] >= NODE_MAX_FAILURES_IN_ROW and res["node"] not in self.banned:
            self.banned.add(res["node"])
            self.books.stats.retired.append(node)
        return final
