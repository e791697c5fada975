"""The same bits on any machine: one BLAS kernel for every process of the workbench.

numpy and scipy ship OpenBLAS built for many CPUs (``DYNAMIC_ARCH``): at load it picks kernels for
the CPU it finds, and kernels for different CPUs sum in different orders.  So the same run on two
x86_64 hosts with the same packages differed in the last bits (measured: the benchmark's reference,
made on a host whose OpenBLAS picked its "Haswell" kernels, against an AMD EPYC host where it picked
"SkylakeX": 24 of 30 runs of one scenario differed, the laws by 1 ulp, the NMPC by 1e-8 relative);
with ``OPENBLAS_CORETYPE=Haswell`` the EPYC host reproduced the reference's 30 runs bit for bit.

:func:`pin` sets ``OPENBLAS_CORETYPE`` to :data:`CORE` (the AVX2/FMA kernels every x86_64 CPU since
2013 runs) unless the environment already sets it or ``STICKSLIP_NATIVE_BLAS=1`` asks for the CPU's
own.  It must run before numpy loads OpenBLAS: ``models`` calls it first thing on import, and the
worker processes inherit the variable (:mod:`mitigate.workers`).  A program that imported numpy
before this package keeps its BLAS as loaded; :func:`blas_core` says which kernels a process runs
(the benchmark records it in its provenance).  This module imports nothing heavy (no numpy).
"""

from __future__ import annotations

import ctypes
import os
import platform

__all__ = ["CORE", "NATIVE_ENV", "pin", "portable_core", "blas_core"]

#: the OpenBLAS kernels every process runs on an x86_64 CPU with AVX2 and FMA
CORE = "Haswell"
#: ``STICKSLIP_NATIVE_BLAS=1``: leave OpenBLAS to pick the CPU's own kernels (faster on large
#: matrices, other last bits)
NATIVE_ENV = "STICKSLIP_NATIVE_BLAS"


def _cpu_flags() -> set[str]:
    try:
        with open("/proc/cpuinfo", encoding="ascii", errors="replace") as f:
            for line in f:
                if line.startswith("flags"):
                    return set(line.split(":", 1)[1].split())
    except OSError:
        pass
    return set()


def portable_core() -> str | None:
    """:data:`CORE` where this CPU runs it (x86_64 with AVX2 and FMA, read from ``/proc/cpuinfo``),
    else None (another architecture: OpenBLAS picks, and results may differ from an x86_64 host's)."""
    if platform.machine().lower() not in ("x86_64", "amd64"):
        return None
    return CORE if {"avx2", "fma"} <= _cpu_flags() else None


def pin(environ=None) -> str | None:
    """Set ``OPENBLAS_CORETYPE`` in ``environ`` (default ``os.environ``) to :func:`portable_core`
    unless it is set or :data:`NATIVE_ENV` is ``1``; returns the value in force (None: OpenBLAS picks)."""
    env = os.environ if environ is None else environ
    if "OPENBLAS_CORETYPE" not in env and env.get(NATIVE_ENV, "") != "1":
        core = portable_core()
        if core is not None:
            env["OPENBLAS_CORETYPE"] = core
    return env.get("OPENBLAS_CORETYPE")


def blas_core() -> str | None:
    """The kernels this process's OpenBLAS runs (e.g. ``"Haswell"``, ``"SkylakeX"``), read from the
    loaded library (Linux: ``/proc/self/maps``); None when no OpenBLAS is loaded or it cannot be asked."""
    try:
        with open("/proc/self/maps", encoding="ascii", errors="replace") as f:
            paths = sorted({ln.split()[-1] for ln in f if "openblas" in ln.lower() and "/" in ln})
    except OSError:
        return None
    for path in paths:
        try:
            lib = ctypes.CDLL(path)
        except OSError:
            continue
        for name in ("scipy_openblas_get_corename64_", "scipy_openblas_get_corename", "openblas_get_corename64_",
                     "openblas_get_corename"):
            fn = getattr(lib, name, None)
            if fn is not None:
                fn.restype = ctypes.c_char_p
                got = fn()
                return got.decode() if got else None
    return None
