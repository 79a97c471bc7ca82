"""Keep OpenBLAS single-threaded while the filter runs.

The filter does tens of thousands of 15x15..21x21 matrix operations; OpenBLAS threads only
add synchronisation cost there (measured ~100x slower `solve` on a loaded 2-core machine).
No extra dependency: the bundled OpenBLAS libraries are reached through ctypes.
"""

from __future__ import annotations

import contextlib
import ctypes
import glob
import os

_SYMBOLS = [("openblas_set_num_threads64_", "openblas_get_num_threads64_"),
            ("scipy_openblas_set_num_threads64_", "scipy_openblas_get_num_threads64_"),
            ("openblas_set_num_threads", "openblas_get_num_threads")]


def _openblas_handles():
    import numpy
    import scipy

    out = []
    for pkg in (numpy, scipy):
        libdir = os.path.join(os.path.dirname(os.path.dirname(pkg.__file__)), f"{pkg.__name__}.libs")
        for path in glob.glob(os.path.join(libdir, "*openblas*.so*")):
            try:
                lib = ctypes.CDLL(path)
            except OSError:
                continue
            for set_name, get_name in _SYMBOLS:
                if hasattr(lib, set_name) and hasattr(lib, get_name):
                    out.append((getattr(lib, set_name), getattr(lib, get_name)))
                    break
    return out


@contextlib.contextmanager
def single_thread_blas():
    try:
        handles = _openblas_handles()
    except Exception:  # an unusual numpy build: run as is
        handles = []
    saved = []
    for set_fn, get_fn in handles:
        try:
            saved.append((set_fn, int(get_fn())))
            set_fn(1)
        except Exception:
            pass
    try:
        yield
    finally:
        for set_fn, n in saved:
            set_fn(n)
