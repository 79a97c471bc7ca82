"""`blendgen gpu-kernels`: which Cycles cubins bpy ships, and compiling a missing one.

The compile tests need `ptxas` (CUDA toolkit or PyPI nvidia-cuda-nvcc-cu12) and are skipped,
saying so, without it; they compile a small PTX, not Cycles' (8 min of CPU)."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest
import zstandard

from blendgen.errors import UserError
from blendgen.render import gpu_kernels as gk

TINY_PTX = """.version 7.0
.target sm_75
.address_size 64
.visible .entry add_one(.param .u64 p)
{
  .reg .b64 %rd<2>;
  .reg .f32 %f<3>;
  ld.param.u64 %rd1, [p];
  cvta.to.global.u64 %rd1, %rd1;
  ld.global.f32 %f1, [%rd1];
  add.f32 %f2, %f1, 0f3F800000;
  st.global.f32 [%rd1], %f2;
  ret;
}
"""


def run_cli(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "blendgen.cli", *args], capture_output=True, text=True, timeout=120)


def _ptxas() -> Path:
    try:
        return gk.find_ptxas()
    except UserError:
        pytest.skip("needs ptxas (CUDA toolkit or `pip install nvidia-cuda-nvcc-cu12`)")


def test_bpy_ships_no_hopper_or_ampere_datacentre_kernel():
    lib = gk.cycles_lib_dir()
    assert (lib / gk.PTX_NAME).is_file()
    have = gk.shipped_archs(lib)
    assert {"sm_75", "sm_86", "sm_89"} <= have
    # what the command exists for (bpy 5.0.1): A100 and H100/H200 JIT-compile the PTX.
    # A cubin made by `blendgen gpu-kernels` on this install would be listed here too.
    assert gk.missing_archs(["sm_80", "sm_86"]) == (["sm_80"] if "sm_80" not in have else [])


@pytest.mark.parametrize("text,arch", [("sm_90", "sm_90"), ("90", "sm_90"), ("9.0", "sm_90"), ("12.0", "sm_120"),
                                       (" SM_86\n", "sm_86")])
def test_parse_arch(text, arch):
    assert gk.parse_arch(text) == arch


def test_cli_errors_are_clear():
    bad = run_cli("gpu-kernels", "--arch", "hopper")
    assert bad.returncode == 2 and "--arch" in bad.stderr and "Traceback" not in bad.stderr
    missing = run_cli("gpu-kernels", "--check", "--arch", "sm_86", "--arch", "sm_37")
    assert missing.returncode == 1, missing.stderr
    assert "sm_86: present" in missing.stdout and "sm_37: missing" in missing.stdout
    noptxas = run_cli("gpu-kernels", "--arch", "sm_37", "--ptxas", "/nonexistent/ptxas")
    assert noptxas.returncode == 2 and "/nonexistent/ptxas" in noptxas.stderr


def test_compile_writes_a_zstd_cubin_atomically(tmp_path):
    ptxas = _ptxas()
    ptx = tmp_path / "k.ptx.zst"
    ptx.write_bytes(zstandard.ZstdCompressor().compress(TINY_PTX.encode()))
    lib = tmp_path / "lib"
    lib.mkdir()
    said = []
    out = gk.compile_cubin("sm_90", ptxas, lib, ptx, progress=said.append)
    assert out == lib / "kernel_sm_90.cubin.zst" and gk.shipped_archs(lib) == {"sm_90"}
    cubin = zstandard.ZstdDecompressor().decompressobj().decompress(out.read_bytes())
    assert cubin[:4] == b"\x7fELF"  # a CUDA cubin is an ELF image
    assert any("ptxas took" in s for s in said)
    assert sorted(p.name for p in lib.iterdir()) == ["kernel_sm_90.cubin.zst"]  # no temp files left


def test_compile_failure_names_the_arch_and_keeps_nothing(tmp_path):
    ptxas = _ptxas()
    ptx = tmp_path / "k.ptx"
    ptx.write_text(TINY_PTX.replace("ret;", "not_an_instruction;"))
    lib = tmp_path / "lib"
    lib.mkdir()
    with pytest.raises(UserError, match="ptxas failed for sm_90"):
        gk.compile_cubin("sm_90", ptxas, lib, ptx, progress=lambda s: None)
    assert list(lib.iterdir()) == []


def test_cuda_release_parsing():
    assert gk._release("Cuda compilation tools, release 13.0, V13.0.88") == (13, 0)
    assert gk._release("| NVIDIA-SMI 580.159.04   Driver Version: 580.159.04   CUDA Version: 13.0 |") == (13, 0)
    assert gk._release("no version here") is None


def test_local_gpus_read_from_nvidia_smi(tmp_path, monkeypatch):
    """Two GPUs and a line that is no compute capability, as nvidia-smi prints them."""
    smi = tmp_path / "nvidia-smi"
    smi.write_text("#!/bin/sh\nprintf '9.0\\n8.0\\n[N/A]\\n9.0\\n'\n")
    smi.chmod(0o755)
    monkeypatch.setenv("PATH", f"{tmp_path}:/usr/bin:/bin")
    assert gk.local_gpu_archs() == ["sm_80", "sm_90"]
    assert "sm_90" in gk.missing_archs() or "sm_90" in gk.shipped_archs(gk.cycles_lib_dir())
