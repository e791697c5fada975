"""A normal (non-editable) install ships every module, subpackage and data file.

The README's command 1 is ``python -m pip install . && mitigate run ...``: that installs the
wheel pip builds, so whatever the wheel lacks is missing on a newcomer's machine (once,
``mitigate.commands`` was).  The editable install the other tests run under cannot see that.

Each build runs in a copy of the working tree without the files .gitignore names
(``build/``, ``*.egg-info``, ...), as in a fresh clone: setuptools re-reads an old
``*.egg-info/SOURCES.txt`` and ships the ``.py`` files it lists as package data, so a build in
a tree that was once packaged correctly hides a package that is no longer found.
"""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
import tarfile
import zipfile
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("models", "estimators", "mitigate")
DATA_SUFFIXES = (".toml", ".c", ".h", ".json")   # rig and parameter files; the compiled steps' C sources; the benchmark's schema
# data files the package-data patterns must cover before any exist in the tree
EXAMPLE_DATA = ("models/rigs/example_rig.toml", "models/data/example_params.toml")


def _ignored() -> list[str]:
    """Name patterns from .gitignore (all of them are plain names or globs), plus .git."""
    pats = [".git"]
    for line in (ROOT / ".gitignore").read_text().splitlines():
        line = line.strip()
        if line and not line.startswith(("#", "!")):
            pats.append(line.rstrip("/"))
    return pats


@pytest.fixture
def clean_tree(tmp_path) -> Path:
    tree = tmp_path / "stickslip-workbench"
    shutil.copytree(ROOT, tree, ignore=shutil.ignore_patterns(*_ignored()))
    return tree


def _run(cmd, cwd, **kw):
    proc = subprocess.run(cmd, cwd=cwd, capture_output=True, text=True, timeout=600, **kw)
    assert proc.returncode == 0, f"{' '.join(map(str, cmd))} failed:\n{proc.stdout[-3000:]}\n{proc.stderr[-3000:]}"


def _build_wheel(source: str, cwd: Path, wheels: Path) -> set[str]:
    """``python -m pip wheel --no-deps SOURCE -w WHEELS`` run in ``cwd`` (how ``pip install`` builds it).

    Returns the wheel's archive names, plus ``"entry_points: <line>"`` for its entry points.
    """
    _run([sys.executable, "-m", "pip", "wheel", "--no-deps", source, "-w", str(wheels)], cwd=cwd)
    built = sorted(wheels.glob("stickslip_workbench-*.whl"))
    assert len(built) == 1, f"expected one wheel, got {[p.name for p in built]}"
    with zipfile.ZipFile(built[0]) as zf:
        names = set(zf.namelist())
        names |= {"entry_points: " + line.strip() for n in list(names) if n.endswith(".dist-info/entry_points.txt")
                  for line in zf.read(n).decode().splitlines()}
    return names


def _expected(tree: Path) -> dict[str, list[str]]:
    """What a wheel of ``tree`` must hold, as archive names, by kind."""
    init, py, data = [], [], []
    for top in PACKAGES:
        for d, dirs, files in os.walk(tree / top):
            dirs[:] = [x for x in dirs if x != "__pycache__"]
            rel = Path(d).relative_to(tree).as_posix()
            if "__init__.py" in files:
                init.append(f"{rel}/__init__.py")
            py += [f"{rel}/{f}" for f in files if f.endswith(".py") and f != "__init__.py"]
            data += [f"{rel}/{f}" for f in files if f.endswith(DATA_SUFFIXES)]
    return {"package": sorted(init), "module": sorted(py), "data file": sorted(data)}


def _assert_ships(names: set[str], expected: dict[str, list[str]], what: str, prefix: str = ""):
    missing = [f"{kind} {n}" for kind, files in expected.items() for n in files if prefix + n not in names]
    missing = [m + (" (its folder has no __init__.py, so it is no package)" if m.startswith("module ")
                    and f"{m[7:].rsplit('/', 1)[0]}/__init__.py" not in expected["package"] else "")
               for m in missing]
    assert not missing, (f"{what} lacks {len(missing)} file(s) of the source tree (see [tool.setuptools.*] in "
                         f"pyproject.toml): " + ", ".join(missing))


def _assert_only_packages(names: set[str]):
    tops = {n.split("/", 1)[0] for n in names if not n.startswith("entry_points: ")}
    extra = sorted(t for t in tops - set(PACKAGES) if not t.endswith(".dist-info"))
    assert not extra, f"the wheel has top-level entries besides {PACKAGES}: {extra}"
    assert "entry_points: mitigate = mitigate.cli:main" in names


@pytest.mark.slow
def test_wheel_ships_every_package_module_and_data_file(clean_tree, tmp_path):
    names = _build_wheel(".", clean_tree, tmp_path / "wheels")
    expected = _expected(clean_tree)
    # the tree has subpackages, so the check cannot pass vacuously
    assert {"mitigate/commands/__init__.py", "mitigate/controllers/__init__.py"} <= set(expected["package"])
    _assert_ships(names, expected, "the wheel")
    _assert_only_packages(names)


@pytest.mark.slow
def test_sdist_and_its_wheel_ship_rig_and_data_files(clean_tree, tmp_path):
    """models/rigs/*.toml and models/data/*.toml reach the sdist, and the wheel built from it.

    The example files are added to the test's copy of the tree only.
    """
    for rel in EXAMPLE_DATA:
        (clean_tree / rel).parent.mkdir(exist_ok=True)
        (clean_tree / rel).write_text("# packaging test\n")
    expected = _expected(clean_tree)
    assert set(EXAMPLE_DATA) <= set(expected["data file"])
    # the sdist, built by the project's own build backend (pyproject [build-system]) in isolation
    backend, dist = tmp_path / "backend", tmp_path / "dist"
    _run([sys.executable, "-m", "pip", "install", "-q", "--target", str(backend), "setuptools>=68", "wheel"],
         cwd=tmp_path)
    _run([sys.executable, "-c", f"import setuptools.build_meta as b; b.build_sdist({str(dist)!r})"],
         cwd=clean_tree, env={**os.environ, "PYTHONPATH": str(backend)})
    sdists = sorted(dist.glob("stickslip_workbench-*.tar.gz"))
    assert len(sdists) == 1, f"expected one sdist, got {[p.name for p in sdists]}"
    with tarfile.open(sdists[0]) as tf:
        top = tf.getnames()[0].split("/", 1)[0]
        _assert_ships(set(tf.getnames()), expected, "the sdist", prefix=top + "/")
    names = _build_wheel(str(sdists[0]), tmp_path, tmp_path / "wheels")
    _assert_ships(names, expected, "the wheel built from the sdist")
    _assert_only_packages(names)
    # models/rigs/ (no __init__.py) stays a data folder: the shipped rig files, not a package
    assert "models/rigs/rig3.toml" in names and "models/rigs/__init__.py" not in names
