"""The benchmarks' zoo rigs are files (``benchmarks/zoo/``): the same rigs whatever the process imported
(hypothesis' draws depend on the modules loaded; ``benchmarks/_zoo_rigs.py``)."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "benchmarks"))


def test_every_frozen_rig_loads_as_what_its_index_says():
    from _zoo_rigs import zoo

    from models import get_model
    rigs = zoo()
    assert len(rigs) == 10 and {f"example_{i}" for i in range(6)} <= set(rigs)
    for name, z in rigs.items():
        path = ROOT / "benchmarks" / "zoo" / f"{name}.toml"
        m = get_model(str(path))
        assert m.drive_input == z.drive_input, name
        assert m.law(m.spec.contacts[0].name).name == z.law, name
        assert m.spec.description == f"generated: {z.n_bodies} bodies, {z.drive} drive, {z.law}", name


def test_the_same_rigs_in_another_import_state():
    """A fresh process that imports only the rig module reads the same texts as one that imported the
    identification benchmark first (the drawn examples 3-5 differed between those two)."""
    code = ("import sys, hashlib; sys.path.insert(0, {b!r}); {pre}from _zoo_rigs import zoo; "
            "print(hashlib.sha1(''.join(z.text for z in zoo().values()).encode()).hexdigest())")
    b = str(ROOT / "benchmarks")
    out = [subprocess.run([sys.executable, "-c", code.format(b=b, pre=pre)], capture_output=True, text=True,
                          cwd=ROOT, check=True).stdout.strip() for pre in ("", "import bench_identify; ")]
    assert out[0] == out[1] and len(out[0]) == 40


def test_asking_for_more_examples_than_frozen_is_one_line():
    from _zoo_rigs import zoo
    with pytest.raises(ValueError, match="holds no rig 'example_6'"):
        zoo(7)
