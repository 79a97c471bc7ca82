"""`blendgen gpu-kernels`: Cycles CUDA kernels for GPUs the bpy wheel ships none for.

Cycles loads `lib/kernel_sm_<major><minor>.cubin` for the GPU's exact compute capability and
otherwise hands the bundled PTX (`kernel_compute_75.ptx`) to the driver, which compiles it on
the first render. bpy 5.0.1 ships cubins for sm_50-75, 86, 89 and 120 only, so an A100 (sm_80)
or H100/H200 (sm_90) compiles on its first render: on an H200 that had not finished after
5.5 min (docs/render.md "On a GPU"). This command compiles the cubin once with `ptxas` (CUDA
toolkit, or `pip install nvidia-cuda-nvcc-cu12`) and puts it beside Blender's, where Cycles
finds it. Reads files only: no bpy import.
"""

from __future__ import annotations

import importlib.util
import re
import shutil
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

from blendgen.atomic import write_bytes
from blendgen.errors import UserError

PTX_NAME = "kernel_compute_75.ptx.zst"


def cycles_lib_dir() -> Path:
    """bpy's Cycles kernel folder (`bpy/<version>/scripts/addons_core/cycles/lib`)."""
    spec = importlib.util.find_spec("bpy")
    if spec is None or not spec.submodule_search_locations:
        raise UserError("bpy (Blender as a Python module) is not installed in this Python")
    libs = sorted(Path(spec.submodule_search_locations[0]).glob("*/scripts/addons_core/cycles/lib"))
    if not libs:
        raise UserError(f"no Cycles kernel folder under {spec.submodule_search_locations[0]}")
    return libs[-1]


def shipped_archs(lib: Path) -> set[str]:
    """Architectures with a cubin in `lib` ({"sm_89", ...})."""
    return {m.group(1) for p in lib.iterdir() if (m := re.fullmatch(r"kernel_(sm_\d+)\.cubin(\.zst)?", p.name))}


def parse_arch(text: str) -> str:
    """'sm_90', '90', '9.0' -> 'sm_90'."""
    t = text.strip().lower().removeprefix("sm_")
    m = re.fullmatch(r"(\d+)\.(\d)|(\d+)", t)
    if not m:
        raise UserError(f"--arch: expected a compute capability such as sm_90, 90 or 9.0, got {text!r}")
    return f"sm_{m.group(1)}{m.group(2)}" if m.group(1) else f"sm_{m.group(3)}"


def local_gpu_archs() -> list[str]:
    """Compute capabilities of this machine's NVIDIA GPUs (nvidia-smi); [] when there are none."""
    exe = shutil.which("nvidia-smi")
    if exe is None:
        return []
    try:
        out = subprocess.run([exe, "--query-gpu=compute_cap", "--format=csv,noheader"],
                             capture_output=True, text=True, timeout=30)
    except (OSError, subprocess.SubprocessError):
        return []
    if out.returncode != 0:
        return []
    # one "9.0" per GPU; anything else ("[N/A]", a driver message) says nothing about kernels
    return sorted({parse_arch(c) for c in out.stdout.split() if re.fullmatch(r"\d+\.\d", c)})


def missing_archs(archs: list[str] | None = None) -> list[str]:
    """The local GPUs' architectures that Cycles would compile on the first render."""
    archs = local_gpu_archs() if archs is None else archs
    if not archs:
        return []
    have = shipped_archs(cycles_lib_dir())
    return [a for a in archs if a not in have]


def _release(text: str) -> tuple[int, int] | None:
    m = re.search(r"(?:release|CUDA Version:)\s*(\d+)\.(\d+)", text)
    return (int(m.group(1)), int(m.group(2))) if m else None


def version_warning(ptxas: Path) -> str | None:
    """A cubin from a ptxas newer than the driver's CUDA may not load: say so before 8 minutes go."""
    exe = shutil.which("nvidia-smi")
    try:
        tool = _release(subprocess.run([str(ptxas), "--version"], capture_output=True, text=True, timeout=30).stdout)
        drv = _release(subprocess.run([exe], capture_output=True, text=True, timeout=30).stdout) if exe else None
    except (OSError, subprocess.SubprocessError):
        return None
    if tool and drv and tool > drv:
        return (f"gpu-kernels: warning: ptxas is CUDA {tool[0]}.{tool[1]}, the driver supports CUDA {drv[0]}.{drv[1]}: "
                "its cubin may not load; use a ptxas no newer than the driver (e.g. nvidia-cuda-nvcc-cu12 "
                f"=={drv[0]}.{drv[1]}.*)")
    return None


def find_ptxas(explicit: str | None = None) -> Path:
    if explicit:
        p = Path(explicit)
        if not p.is_file():
            raise UserError(f"--ptxas: {p} is not a file")
        return p
    found = shutil.which("ptxas")
    if found:
        return Path(found)
    spec = importlib.util.find_spec("nvidia")  # PyPI nvidia-cuda-nvcc-cu12 installs nvidia/cuda_nvcc/bin/ptxas
    for root in (spec.submodule_search_locations or []) if spec else []:
        p = Path(root) / "cuda_nvcc" / "bin" / "ptxas"
        if p.is_file():
            return p
    raise UserError("ptxas not found: install the CUDA toolkit or `pip install nvidia-cuda-nvcc-cu12`, "
                    "or pass --ptxas PATH")


def _say(text: str) -> None:
    print(text, flush=True)  # progress must show in non-tty farm logs too


def compile_cubin(arch: str, ptxas: Path, lib: Path, ptx: Path | None = None, *, progress=_say) -> Path:
    """Compile the bundled PTX (or `ptx`, a .ptx or .ptx.zst file) for `arch` and write
    lib/kernel_<arch>.cubin.zst atomically (Blender's own kernels are zstd-compressed)."""
    import zstandard  # bpy's own dependency

    src = ptx or lib / PTX_NAME
    if not src.is_file():
        raise UserError(f"no PTX to compile: {src} does not exist")
    out = lib / f"kernel_{arch}.cubin.zst"
    if not _writable(lib):
        raise UserError(f"cannot write to {lib}: run this command as the user that installed bpy, "
                        "or in an environment you own")
    with tempfile.TemporaryDirectory(prefix="blendgen_ptxas_") as tmp:
        ptx_file = Path(tmp) / "kernel.ptx"
        data = src.read_bytes()
        ptx_file.write_bytes(zstandard.ZstdDecompressor().decompressobj().decompress(data)
                             if src.suffix == ".zst" else data)
        cubin = Path(tmp) / "kernel.cubin"
        cmd = [str(ptxas), f"-arch={arch}", str(ptx_file), "-o", str(cubin)]
        progress(f"gpu-kernels: compiling {src.name} for {arch} with {ptxas} "
                 "(about 8 min of one CPU core for Cycles' kernel) ...")
        proc = _run_with_heartbeat(cmd, progress)
        if proc.returncode != 0 or not cubin.is_file():
            raise UserError(f"ptxas failed for {arch} (exit {proc.returncode}): {proc.stderr.strip()[-800:]}")
        write_bytes(out, zstandard.ZstdCompressor(level=19).compress(cubin.read_bytes()))
    return out


def _run_with_heartbeat(cmd: list[str], progress, every_s: float = 60.0):
    """Run `cmd`, saying every minute that it still runs (ptxas prints nothing for minutes)."""
    t0 = time.monotonic()
    done = threading.Event()

    def beat():
        while not done.wait(every_s):
            progress(f"gpu-kernels: ... {time.monotonic() - t0:.0f} s")

    threading.Thread(target=beat, daemon=True).start()
    try:
        proc = subprocess.run(cmd, capture_output=True, text=True)
    finally:
        done.set()
    progress(f"gpu-kernels: ptxas took {time.monotonic() - t0:.0f} s")
    return proc


def _writable(folder: Path) -> bool:
    try:
        with tempfile.NamedTemporaryFile(dir=folder):
            return True
    except OSError:
        return False


def register(subparsers) -> None:
    p = subparsers.add_parser(
        "gpu-kernels", help="compile Cycles' CUDA kernel for this machine's GPU when bpy ships none",
        description="Cycles needs a CUDA kernel (cubin) for the GPU's exact compute capability; bpy 5.0.1 "
                    "ships none for sm_80 (A100) or sm_90 (H100, H200), and the driver then compiles the "
                    "bundled PTX on the first render (over 5 min on an H200). This compiles it once with "
                    "ptxas and stores it beside Blender's kernels. Run it once per environment (image) "
                    "that renders with `render.device: GPU`.")
    p.add_argument("--arch", action="append", help="compute capability to build for (sm_90, 9.0); "
                                                   "repeatable; default: this machine's GPUs (nvidia-smi)")
    p.add_argument("--ptxas", help="the ptxas to use (default: PATH, then PyPI nvidia-cuda-nvcc-cu12)")
    p.add_argument("--check", action="store_true", help="only report what is shipped and what is missing "
                                                      "(exit 1 when a kernel is missing)")
    p.set_defaults(func=_run)


def _run(args) -> int:
    lib = cycles_lib_dir()
    have = shipped_archs(lib)
    archs = [parse_arch(a) for a in args.arch] if args.arch else local_gpu_archs()
    if not archs:
        raise UserError("no NVIDIA GPU found here (nvidia-smi); name the target with --arch, e.g. --arch sm_90")
    print(f"gpu-kernels: {lib} has cubins for {', '.join(sorted(have, key=lambda a: int(a[3:])))}")
    missing = [a for a in archs if a not in have]
    for a in archs:
        print(f"  {a}: {'missing: the first render would compile the PTX' if a in missing else 'present'}")
    if args.check or not missing:
        return 1 if missing else 0
    ptxas = find_ptxas(args.ptxas)
    if warning := version_warning(ptxas):
        print(warning, file=sys.stderr)
    for a in missing:
        print(f"gpu-kernels: wrote {compile_cubin(a, ptxas, lib)}")
    return 0
