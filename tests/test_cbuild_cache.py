"""The compiled-code cache outlives the environment that filled it: a library linking hpipm and
blasfeo built from one copy of them is found, by the same key, from another copy elsewhere (a
fresh virtual environment), and still loads after both copies are gone (models.cbuild)."""

from __future__ import annotations

import ctypes
import shutil

import pytest

from models.cbuild import build_library, hpipm_paths, stage_libraries

SRC = """#include "hpipm_d_ocp_qp_dim.h"
/* a call into hpipm, so that the library really links it */
long long ss_probe_dim_memsize(int N) { return (long long) d_ocp_qp_dim_memsize(N); }
"""


def _copy_of_the_wheels_libraries(dest):
    _, lib = hpipm_paths()
    dest.mkdir()
    for f in list(lib.glob("libhpipm.so*")) + list(lib.glob("libblasfeo.so*")):
        shutil.copyfile(f, dest / f.name)
    return dest


@pytest.mark.skipif(shutil.which("cc") is None and shutil.which("gcc") is None, reason="needs a C compiler")
def test_a_library_built_in_one_environment_is_reused_and_loads_from_another(tmp_path):
    inc, _ = hpipm_paths()
    first, second = (_copy_of_the_wheels_libraries(tmp_path / n) for n in ("venv1", "venv2"))
    files = {"probe.c": SRC + f"/* {tmp_path.name} */\n"}          # a key of this test's own
    a = build_library("probe", files, ["probe.c"], include=[inc], libs=["hpipm", "blasfeo"], libdirs=[first])
    b = build_library("probe", files, ["probe.c"], include=[inc], libs=["hpipm", "blasfeo"], libdirs=[second])
    assert a == b                                          # one key: the content linked, not its path
    staged = stage_libraries(["hpipm", "blasfeo"], [first])
    assert staged == stage_libraries(["hpipm", "blasfeo"], [second])
    before = {f.name: f.stat().st_mtime_ns for f in staged.iterdir()}
    assert stage_libraries(["blasfeo", "hpipm"], [first]) == staged       # staged once, in any order
    assert {f.name: f.stat().st_mtime_ns for f in staged.iterdir()} == before
    shutil.rmtree(first)
    shutil.rmtree(second)                                  # both environments gone
    lib = ctypes.CDLL(str(a))
    lib.ss_probe_dim_memsize.restype = ctypes.c_longlong
    assert lib.ss_probe_dim_memsize(5) > 0


def test_a_library_that_is_nowhere_is_one_line(tmp_path):
    with pytest.raises(RuntimeError, match=r"^libnope\.so not found in "):
        stage_libraries(["nope"], [tmp_path])


def test_an_export_vendors_the_blasfeo_named_by_the_environment(tmp_path, monkeypatch):
    """STICKSLIP_BLASFEO names a blasfeo built for the target CPU (the wheel's is the generic build):
    ``mitigate export`` vendors it as ``lib/libblasfeo.so.0`` (hpipm's name for it) and says so in
    PLATFORM; unset, the wheel's is vendored."""
    from mitigate.export.files import vendor_hpipm
    from models.cbuild import BLASFEO_ENV, blasfeo_override
    _, lib = hpipm_paths()
    monkeypatch.delenv(BLASFEO_ENV, raising=False)
    assert blasfeo_override() is None
    vendor_hpipm(tmp_path / "plain")
    assert (tmp_path / "plain" / "lib" / "libblasfeo.so.0").read_bytes() == (lib / "libblasfeo.so.0").read_bytes()
    # "another build": the wheel's bytes with a trailer (an ELF loader ignores trailing bytes)
    other = tmp_path / "libblasfeo.so"
    other.write_bytes((lib / "libblasfeo.so").read_bytes() + b"another build\0")
    monkeypatch.setenv(BLASFEO_ENV, str(other))
    assert blasfeo_override() == other
    vendor_hpipm(tmp_path / "opt")
    assert (tmp_path / "opt" / "lib" / "libblasfeo.so.0").read_bytes() == other.read_bytes()
    assert (tmp_path / "opt" / "lib" / "libhpipm.so").read_bytes() == (lib / "libhpipm.so").read_bytes()
    assert f"blasfeo from {other} (STICKSLIP_BLASFEO)" in (tmp_path / "opt" / "PLATFORM").read_text()


@pytest.mark.parametrize("what, match", [
    ("nothing", r"^STICKSLIP_BLASFEO: expected the path of a libblasfeo\.so file; got '.*nothing' \(no such file\)$"),
    ("text", r"^STICKSLIP_BLASFEO: expected a blasfeo shared library; got '.*libblasfeo\.so' \(OSError: "),
])
def test_a_wrong_blasfeo_override_is_one_line(what, match, tmp_path, monkeypatch):
    from models.cbuild import BLASFEO_ENV, blasfeo_override
    from models.errors import ConfigError
    (tmp_path / "libblasfeo.so").write_text("not a library\n")
    monkeypatch.setenv(BLASFEO_ENV, str(tmp_path / what if what == "nothing" else tmp_path / "libblasfeo.so"))
    with pytest.raises(ConfigError, match=match):
        blasfeo_override()


def test_mitigate_export_refuses_a_wrong_blasfeo_in_one_line(tmp_path):
    import os
    import subprocess
    import sys
    from pathlib import Path
    root = Path(__file__).resolve().parents[1]
    env = dict(os.environ, STICKSLIP_BLASFEO=str(tmp_path / "nothing.so"))
    out = tmp_path / "export"
    r = subprocess.run([sys.executable, "-m", "mitigate.cli", "export", str(root / "scenarios" / "stick_slip_30rpm.toml"),
                        "--controller", "NMPC", "--out", str(out)], capture_output=True, text=True, env=env, cwd=root,
                       timeout=300)
    assert r.returncode == 2
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and "STICKSLIP_BLASFEO: expected the path of a libblasfeo.so file" in lines[0]
    assert not out.exists()


def _dynamic_names(path):
    """(SONAME, NEEDED...) of an ELF library as `readelf -d` prints them (an independent reader)."""
    import re
    import subprocess
    out = subprocess.run(["readelf", "-d", str(path)], capture_output=True, text=True, check=True).stdout
    return (re.findall(r"\(SONAME\)\s+Library soname: \[(.*)\]", out),
            re.findall(r"\(NEEDED\)\s+Shared library: \[(.*)\]", out))


@pytest.mark.skipif(shutil.which("readelf") is None, reason="needs readelf (binutils)")
def test_renamed_copies_of_hpipm_and_blasfeo_need_each_other_by_their_new_names(tmp_path):
    """stage_optimised: hpipm's copy is libhpipX.so and needs libblasfeX.so; the blasfeo's copy is
    libblasfeX.so; nothing else in them changed (the same size, the same bytes outside the names)."""
    from models.cbuild import rename_dynamic, stage_optimised
    _, lib = hpipm_paths()
    d = stage_optimised(lib / "libblasfeo.so", lib)
    assert _dynamic_names(d / "libhpipX.so") == (["libhpipX.so"], ["libblasfeX.so", "libc.so.6"])
    assert _dynamic_names(d / "libblasfeX.so")[0] == ["libblasfeX.so"]
    a, b = (lib / "libhpipm.so").read_bytes(), (d / "libhpipX.so").read_bytes()
    assert len(a) == len(b) and sum(x != y for x, y in zip(a, b)) <= len("libblasfeo.so.0") + len("libhpipm.so")
    with pytest.raises(ValueError, match="is longer than"):
        rename_dynamic(a, {"libhpipm.so": "libhpipm_longer.so"})
    with pytest.raises(ValueError, match="not a 64-bit little-endian ELF"):
        rename_dynamic(b"#!/bin/sh\n", {})
    from models.errors import ConfigError
    (tmp_path / "libblasfeo.so").write_bytes(b"#!/bin/sh\n")
    with pytest.raises(ConfigError, match=r"^STICKSLIP_BLASFEO: expected a 64-bit ELF blasfeo library the workbench "
                                          r"can link; got '.*libblasfeo\.so' \(not a 64-bit little-endian ELF file\)$"):
        stage_optimised(tmp_path / "libblasfeo.so", lib)


@pytest.mark.slow
@pytest.mark.skipif(shutil.which("cc") is None and shutil.which("gcc") is None, reason="needs a C compiler")
def test_the_workbench_nmpc_step_links_the_blasfeo_named_by_the_environment(tmp_path):
    """With STICKSLIP_BLASFEO the workbench's compiled NMPC step links that blasfeo (renamed copies:
    the process has the wheel's loaded through casadi) and the process maps it; pointed at a copy of
    the wheel's own build, the actions are bit for bit the default's (the same kernels)."""
    import os
    import subprocess
    import sys
    from pathlib import Path
    root = Path(__file__).resolve().parents[1]
    _, lib = hpipm_paths()
    other = tmp_path / "libblasfeo.so"
    other.write_bytes((lib / "libblasfeo.so").read_bytes() + b"another build\0")
    script = (
        "import sys, numpy as np\n"
        "sys.path.insert(0, 'tests')\n"
        "from test_nmpc_closed_loop import _closed_loop, _ctx, M, P, W0\n"
        "from models.plant import Plant, SimOptions\n"
        "from mitigate.controllers.factory import make_controller\n"
        "u = np.array([W0, 20.0, 0.0])\n"
        "c = make_controller({'kind': 'nmpc', 'horizon': 10}, _ctx(programme=u))\n"
        "plant = Plant(M, P, SimOptions(seed=0), sensors=None, u0=u)\n"
        "_, acts, _ = _closed_loop(c, plant, 0.0, 200, u_prog=u)\n"
        "maps = open('/proc/self/maps').read()\n"
        "print('blasfeX' if 'libblasfeX.so' in maps else 'wheel', c.counts.failures)\n"
        "print(repr([a.u.get('omega_ref') for a in acts]))\n")
    runs = {}
    for label, extra in (("default", {}), ("override", {"STICKSLIP_BLASFEO": str(other)})):
        env = {k: v for k, v in os.environ.items() if k != "STICKSLIP_BLASFEO"} | extra
        r = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, env=env, cwd=root,
                           timeout=600)
        assert r.returncode == 0, r.stderr[-2000:]
        runs[label] = r.stdout.splitlines()
    assert runs["default"][0] == "wheel 0" and runs["override"][0] == "blasfeX 0"
    assert runs["default"][1] == runs["override"][1]
