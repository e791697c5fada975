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
