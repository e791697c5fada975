"""Compiled CasADi Functions, cached on disk.

Function evaluation dominates the cost of the NMPC, the MHE, the EKF, the batched plant
of the sweeps and the identification (``shared/CASADI-FACTS.md``: compiling is 12-15x
faster), so those generate C for a *small* Function (one stage, one step), build it with
gcc once, and cache the shared library by the hash of its C source (plus the CasADi
version and the optimisation flag).  The cache folder is ``$STICKSLIP_CACHE``, else
``$XDG_CACHE_HOME/stickslip``, else ``~/.cache/stickslip``.  Libraries are written via a
temporary file and renamed, so parallel processes never load a half-written library.
Nothing is written into the working directory.

Loading a shared library runs its code, so the cache is trusted only as far as it is yours
(:func:`trusted_cache_dir`): the folder is created ``0700``; a folder owned by another user, or
writable by the group or the world, is refused (a RuntimeError naming it: set
``$STICKSLIP_CACHE`` to a folder of your own; callers then keep the uncompiled CasADi call where
they can).  Each library is written with a sidecar ``<library>.sha256`` (the SHA-256 of the
library's bytes) and checked against it before every load; a library that is not yours, is
writable by others, has no sidecar or does not match it is rebuilt, never loaded.

The compiled steps (:func:`models.cbuild.build_library`: the NMPC's, the EKF's, the laws') are built
as one of :data:`BUILD_TYPES`: ``Release`` (optimised; the default, the build ``BENCHMARKS.md`` times)
or ``Debug`` (unoptimised: the 2.7 MB of generated C of rig3's NMPC step compiles in 12 s instead of
40 s, runs a few per cent slower, and gives the same bits: strict IEEE arithmetic in both).  The
environment variable ``STICKSLIP_BUILD_TYPE`` chooses (:func:`build_type`); the test suite sets
``Debug`` (``tests/conftest.py``).  The build type is part of their cache keys.  The small Functions
of :func:`compile_cached` (a plant step, a shooting interval's sensitivities: quick to compile, and
evaluated millions of times by a simulation or a fit) keep the optimisation their caller asks for.
"""

from __future__ import annotations

import ctypes
import hashlib
import hmac
import os
import shutil
import stat
import subprocess
import tempfile
from pathlib import Path
from typing import Sequence

import casadi as ca
import numpy as np

__all__ = ["BUILD_TYPES", "build_type", "cache_dir", "trusted_cache_dir", "compiler", "compile_cached", "load_compiled", "compiled_or_none",
           "verify_library", "store_built", "CtypesFunction", "FastFunction",
           "BufferedFunction"]


#: the build types and their optimisation flags (one declaration: the compiled steps, the exports'
#: CMakeLists.txt and Makefile all read it)
BUILD_TYPES = {"Release": "-O2", "Debug": "-O0 -g"}


def build_type() -> str:
    """``$STICKSLIP_BUILD_TYPE`` (one of :data:`BUILD_TYPES`), else ``"Release"``.

    Raises
    ------
    ConfigError : the variable names no build type (one line naming it).
    """
    v = os.environ.get("STICKSLIP_BUILD_TYPE") or "Release"
    if v not in BUILD_TYPES:
        from models.errors import ConfigError
        raise ConfigError(f"STICKSLIP_BUILD_TYPE: expected one of {', '.join(BUILD_TYPES)}; got {v!r}")
    return v


def opt_flags() -> list[str]:
    """The optimisation flags of the build type now (:func:`build_type`)."""
    return BUILD_TYPES[build_type()].split()


def reproducible(flags, folder) -> list[str]:
    """``flags`` plus, with debug information (``-g``), the build ``folder`` mapped to ``.`` in it: the
    same bytes from every build (the folder is a fresh temporary one)."""
    return [*flags, f"-fdebug-prefix-map={folder}=."] if "-g" in flags else list(flags)


def cache_dir() -> Path:
    """``$STICKSLIP_CACHE``, else ``$XDG_CACHE_HOME/stickslip``, else ``~/.cache/stickslip``."""
    env = os.environ.get("STICKSLIP_CACHE")
    if env:
        return Path(env)
    base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    return Path(base) / "stickslip"


def trusted_cache_dir() -> Path:
    """:func:`cache_dir`, created ``0700`` if missing; a RuntimeError if it is not a folder of this
    user's that only this user can write (module docstring)."""
    d = cache_dir()
    try:
        d.mkdir(mode=0o700, parents=True, exist_ok=True)
        st = d.stat()
    except OSError as exc:
        raise RuntimeError(f"compiled-code cache {d}: cannot create it ({exc.strerror or exc})") from None
    if not stat.S_ISDIR(st.st_mode):
        raise RuntimeError(f"compiled-code cache {d} is not a folder")
    if hasattr(os, "getuid") and st.st_uid != os.getuid():
        raise RuntimeError(f"compiled-code cache {d} belongs to user id {st.st_uid}, not to you ({os.getuid()}); "
                           f"refusing to load code from it (set STICKSLIP_CACHE to a folder of your own)")
    if st.st_mode & 0o022:
        raise RuntimeError(f"compiled-code cache {d} is writable by {'others' if st.st_mode & 0o002 else 'its group'} "
                           f"(mode {stat.S_IMODE(st.st_mode):o}); refusing to load code from it (chmod 700 it, or set "
                           f"STICKSLIP_CACHE to a folder of your own)")
    return d


def _digest(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def verify_library(so: Path) -> bool:
    """Whether the cached library ``so`` may be loaded: a regular file of this user's, not writable
    by others, whose bytes match its sidecar ``<so>.sha256`` written when it was built."""
    try:
        st = so.lstat()
        sidecar = so.with_name(so.name + ".sha256").read_text().strip()
    except OSError:
        return False
    if not stat.S_ISREG(st.st_mode) or st.st_mode & 0o022:
        return False
    if hasattr(os, "getuid") and st.st_uid != os.getuid():
        return False
    try:
        return hmac.compare_digest(sidecar, _digest(so))
    except OSError:
        return False


def compiler() -> str | None:
    """Path of the C compiler (gcc or cc), or None."""
    return shutil.which("gcc") or shutil.which("cc")


def compile_cached(functions: ca.Function | Sequence[ca.Function], opt: str = "-O2", tag: str | None = None) -> Path:
    """Generate C for ``functions``, build a shared library, cache it; return its path.

    Parameters
    ----------
    functions : one Function or several (they share one library)
    opt : gcc optimisation flag
    tag : library name stem (default: the first Function's name)

    Raises
    ------
    RuntimeError : no C compiler, or the build failed (first 300 characters of gcc's error).
    """
    fns = [functions] if isinstance(functions, ca.Function) else list(functions)
    tag = tag or fns[0].name()
    cc = compiler()
    if cc is None:
        raise RuntimeError("no C compiler (gcc/cc) found")
    cg = ca.CodeGenerator(f"{tag}.c", {"with_header": False})
    for fn in fns:
        cg.add(fn)
    src = cg.dump()
    flags = opt.split()
    key = hashlib.sha256((ca.__version__ + opt + src).encode()).hexdigest()[:16]
    d = trusted_cache_dir()
    so = d / f"{tag}_{key}.so"
    if verify_library(so):
        return so
    with tempfile.TemporaryDirectory(prefix="stickslip_cg_") as tmp:
        c = Path(tmp) / f"{tag}.c"
        c.write_text(src)
        part = d / f".{so.name}.{os.getpid()}.tmp"
        # a relative source name: the same bytes from every build (parallel builders agree on the hash)
        res = subprocess.run([cc, *reproducible(flags, tmp), "-fPIC", "-shared", c.name, "-o", str(part.absolute()), "-lm"],
                             capture_output=True, text=True, cwd=tmp)
        if res.returncode != 0:
            if part.exists():
                part.unlink()
            raise RuntimeError(f"{cc} failed building {tag}: {res.stderr.strip()[:300]}")
        store_built(part, so)
    return so


def store_built(part: Path, so: Path) -> Path:
    """Move a freshly built library ``part`` to its cache name ``so`` with its sidecar hash (the
    sidecar first: a library never lacks it), and check it.

    Raises
    ------
    RuntimeError : another process replaced it meanwhile and theirs does not verify.
    """
    os.chmod(part, 0o700)
    side = so.parent / f".{so.name}.sha256.{os.getpid()}.tmp"
    side.write_text(_digest(part) + "\n")
    os.replace(side, so.with_name(so.name + ".sha256"))
    os.replace(part, so)
    if not verify_library(so):
        raise RuntimeError(f"compiled library {so} does not match its sidecar hash after building; refusing to load it")
    return so


def load_compiled(functions: ca.Function | Sequence[ca.Function], opt: str = "-O2",
                  tag: str | None = None) -> dict[str, ca.Function]:
    """Compile (cached) and load as ``casadi.external`` Functions, keyed by name."""
    fns = [functions] if isinstance(functions, ca.Function) else list(functions)
    so = compile_cached(fns, opt, tag)
    return {fn.name(): ca.external(fn.name(), str(so)) for fn in fns}


def compiled_or_none(fn: ca.Function, opt: str = "-O2", tag: str | None = None) -> ca.Function | None:
    """``fn`` compiled with gcc and loaded (cached on disk), or None when there is no compiler or the
    build fails: the one compile-with-fallback of the workbench (callers keep ``fn`` then)."""
    try:
        return load_compiled(fn, opt, tag)[fn.name()]
    except (RuntimeError, OSError):
        return None


class CtypesFunction:
    """Call a generated CasADi function in a shared library with preallocated numpy buffers.

    ``self.inputs[i]`` / ``self.outputs[j]`` are float64 arrays (dense, column-major for
    matrices) bound once to the C argument/result pointers; fill the inputs, call
    :meth:`__call__`, read the outputs.  No allocation per call: this is what brings a
    small compiled step (EKF) to a few microseconds from Python.
    """

    def __init__(self, so_path: Path, fn: ca.Function):
        self._lib = ctypes.CDLL(str(so_path))
        name = fn.name()
        self._f = getattr(self._lib, name)
        self._f.restype = ctypes.c_int
        self._f.argtypes = [ctypes.c_void_p] * 4 + [ctypes.c_int]
        for i in range(fn.n_in()):
            if not fn.sparsity_in(i).is_dense():
                raise ValueError(f"{name}: input {i} is not dense")
        for i in range(fn.n_out()):
            if not fn.sparsity_out(i).is_dense():
                raise ValueError(f"{name}: output {i} is not dense")
        self.inputs = [np.zeros(fn.nnz_in(i)) for i in range(fn.n_in())]
        self.outputs = [np.zeros(fn.nnz_out(i)) for i in range(fn.n_out())]
        self._arg = (ctypes.c_void_p * max(fn.sz_arg(), 1))()
        self._res = (ctypes.c_void_p * max(fn.sz_res(), 1))()
        for i, b in enumerate(self.inputs):
            self._arg[i] = b.ctypes.data
        for i, b in enumerate(self.outputs):
            self._res[i] = b.ctypes.data
        self._iw = (ctypes.c_longlong * max(fn.sz_iw(), 1))()
        self._w = np.zeros(max(fn.sz_w(), 1))
        self._args = (ctypes.addressof(self._arg), ctypes.addressof(self._res), ctypes.addressof(self._iw),
                      self._w.ctypes.data, 0)

    def __call__(self) -> None:
        if self._f(*self._args) != 0:
            raise RuntimeError("compiled function returned an error")


class FastFunction:
    """Call a CasADi Function with numpy arrays, compiled and through ctypes when possible.

    The CasADi Python call costs ~0.1 ms per call (argument conversion); a compiled Function
    called through :class:`CtypesFunction` with preallocated buffers costs a few microseconds.
    ``__call__(*args)`` returns the outputs as flat float arrays (column-major), copies.  Without a
    compiler (or for a Function that cannot be generated, such as a CVODES integrator) it falls back
    to the CasADi call; ``compiled`` says which.
    """

    def __init__(self, fn: ca.Function, compile: bool = True):
        self.fn = fn
        self._c = None
        if compile:
            try:
                self._c = CtypesFunction(compile_cached(fn), fn)
            except Exception:  # noqa: BLE001 - any failure keeps the CasADi call
                self._c = None

    @property
    def compiled(self) -> bool:
        return self._c is not None

    def __call__(self, *args) -> list[np.ndarray]:
        c = self._c
        if c is not None:
            for buf, a in zip(c.inputs, args):
                if type(a) is float or (type(a) is np.ndarray and a.ndim <= 1):
                    buf[:] = a                      # the same values, without the ravel (every sample)
                else:
                    buf[:] = np.ravel(np.asarray(a, dtype=float), order="F")
            c()
            return [o.copy() for o in c.outputs]
        out = self.fn(*args)
        out = out if isinstance(out, (list, tuple)) else [out]
        return [np.asarray(o, dtype=float).ravel(order="F") for o in out]


class BufferedFunction:
    """Call any CasADi Function (a thread-parallel map, an external) with numpy arrays, through
    CasADi's ``Function.buffer()``: inputs are copied into preallocated column-major arrays and the
    outputs are written straight into others, with no DM in between.

    For large outputs the DM conversion dominates the call (``DM.full()`` goes through a Python list):
    a 600-interval map of a 9-state sample function with its Jacobians took 35 ms per call that way
    and 4 ms through the buffers.  ``__call__(*args)`` returns the outputs as 2-D arrays of the
    Function's shapes (copies; scalars as (1, 1)).  A Function with a sparse output keeps the plain
    call (``buffered`` says which).
    """

    def __init__(self, fn: ca.Function):
        self.fn = fn
        self.buffered = all(fn.sparsity_out(i).is_dense() for i in range(fn.n_out())) and \
            all(fn.sparsity_in(i).is_dense() for i in range(fn.n_in()))
        if not self.buffered:
            return
        self._in = [np.zeros(fn.size_in(i), order="F") for i in range(fn.n_in())]
        self._out = [np.zeros(fn.size_out(i), order="F") for i in range(fn.n_out())]
        self._buf, self._eval = fn.buffer()
        for i, a in enumerate(self._in):
            self._buf.set_arg(i, memoryview(a.reshape(-1, order="F")))
        for i, a in enumerate(self._out):
            self._buf.set_res(i, memoryview(a.reshape(-1, order="F")))

    def __call__(self, *args) -> list[np.ndarray]:
        if not self.buffered:
            out = self.fn(*args)
            out = out if isinstance(out, (list, tuple)) else [out]
            return [np.asarray(o, dtype=float).reshape(self.fn.size_out(i)) for i, o in enumerate(out)]
        for buf, a in zip(self._in, args):
            a = np.asarray(a, dtype=float)
            # a map's input given for one instance is repeated over all of them, as in the plain call
            buf[...] = a.reshape(buf.shape) if a.size == buf.size else np.tile(np.reshape(a, (buf.shape[0], -1)), (1, buf.shape[1] // max(a.size // buf.shape[0], 1)))
        self._eval()
        return [o.copy() for o in self._out]
