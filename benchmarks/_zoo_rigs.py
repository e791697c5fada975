"""Fixed rigs of the rig zoo (``tests/rig_zoo.py``) and their identification cases, for the benchmarks.

The zoo's generator is a hypothesis strategy; here it is drawn deterministically, as
``tests/test_rig_zoo.py`` draws it: the four CI corners (``CORNERS``, each at its seed) and the first
derandomised examples of up to 3 bodies.  **The benchmarks read the drawn rigs from files**
(``benchmarks/zoo/``, :func:`zoo`): hypothesis (6.170) mines literal constants from the modules
loaded in the process, so the same derandomised draw gave other examples 3-5 depending on what had
been imported (``bench_identify_zoo.py`` and ``identify_coverage.py`` drew different ``example_4``s);
the files are the rigs of the published tables, written with ``python benchmarks/_zoo_rigs.py
--freeze`` in ``bench_identify_zoo.py``'s import state.  :func:`case` turns a rig into an identification case: a
60 s log of the exact plant (the rig's sensors and their noise) from rest at the operating point,
up to 6 free parameters (the first spring's stiffness and damping, the second spring's stiffness,
the contact's kinetic and static levels) started 20 % off.  A user's rig file
(``tests/data/userrig/pin_rig.toml``, a student's 2-disc rig on a DC gear motor) is one more case.

Imported by ``bench_identify_zoo.py`` and ``identify_coverage.py``; not a benchmark itself.
"""

from __future__ import annotations

import math
import sys
import tempfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests"))
from rig_zoo import CORNERS, ZooRig, zoo_rigs  # noqa: E402 - the tests' generator and corners, not copies

from models import get_model  # noqa: E402
from models.modal import operating_point  # noqa: E402
from models.plant import SimOptions, simulate  # noqa: E402

USER_RIG = ROOT / "tests" / "data" / "userrig" / "pin_rig.toml"


def _draw(strategy, seed=None, n: int = 1) -> list[ZooRig]:
    from hypothesis import HealthCheck, Phase, given, settings
    from hypothesis import seed as with_seed
    got: list[ZooRig] = []

    @settings(max_examples=n, deadline=None, database=None, derandomize=seed is None,
              suppress_health_check=list(HealthCheck), phases=(Phase.explicit, Phase.generate))
    @given(z=strategy)
    def one(z):
        got.append(z)

    (with_seed(seed)(one) if seed is not None else one)()
    return got


FROZEN = ROOT / "benchmarks" / "zoo"


def draw_zoo(examples: int = 6) -> dict[str, ZooRig]:
    """Draw the corners (their CI seeds) and the first ``examples`` derandomised rigs of up to 3 bodies
    (hypothesis: what it draws depends on the modules loaded, module docstring)."""
    out = {name: _draw(zoo_rigs(max_bodies=3, **kw), seed=i + 18)[0] for i, (name, kw) in enumerate(CORNERS.items())}
    for i, z in enumerate(_draw(zoo_rigs(max_bodies=3), n=examples) if examples > 0 else []):
        out[f"example_{i}"] = z
    return out


def freeze(rigs: dict[str, ZooRig], folder: Path = FROZEN) -> None:
    """Write each rig's TOML (``NAME.toml``) and what it was drawn from (``index.json``)."""
    import dataclasses
    import json
    folder.mkdir(parents=True, exist_ok=True)
    index = {}
    for name, z in rigs.items():
        (folder / f"{name}.toml").write_text(z.text)
        index[name] = {k: v for k, v in dataclasses.asdict(z).items() if k != "text"}
    (folder / "index.json").write_text(json.dumps(index, indent=1) + "\n")


def zoo(examples: int = 6) -> dict[str, ZooRig]:
    """The frozen rigs (``benchmarks/zoo/``): the four corners and the first ``examples`` examples."""
    import json
    index = json.loads((FROZEN / "index.json").read_text())
    names = [n for n in index if not n.startswith("example_")] + [f"example_{i}" for i in range(examples)]
    missing = [n for n in names if n not in index]
    if missing:
        raise ValueError(f"benchmarks/zoo/ holds no rig {missing[0]!r} (frozen: {', '.join(index)})")
    return {n: ZooRig(text=(FROZEN / f"{n}.toml").read_text(), **{k: tuple(v) if isinstance(v, list) else v
                                                                   for k, v in index[n].items()}) for n in names}


@dataclass
class Case:
    """An identification case: the rig, its true set, a log, the free parameters and the start
    (``start`` None: the data-derived guess, as ``mitigate identify`` without ``--params``)."""

    name: str
    model: object
    truth: object
    free: tuple
    start: object
    describe: str
    encoder_zero: str = "untwisted"
    holdout: float = 0.0
    speed_up: float = 1.0

    def log(self, seed: int = 3, duration: float = 60.0, sensors=None):
        """A log of the exact plant from rest at the operating point (sensor noise seeded by ``seed``);
        with ``speed_up`` the drive's set-point steps to that multiple of it for the last third (the
        user rig: stick-slip, then steady sliding); ``sensors``: :class:`models.sensors.SensorOptions`."""
        u, _ = operating_point(self.model, self.truth)
        if self.speed_up != 1.0:
            j = self.model.inputs.index(self.model.drive_input)
            u0, t1 = np.asarray(u, float), 2.0 * duration / 3.0

            def u(t, u0=u0, j=j, t1=t1):
                v = u0.copy()
                if t >= t1:
                    v[j] *= self.speed_up
                return v
        return simulate(self.model, self.truth, u, duration, SimOptions(seed=seed), sensors=sensors).to_log()


def free_parameters(model) -> tuple[str, ...]:
    """Up to 6: k0, c0, k1, the contact's kinetic and static levels (zoo rigs); k2, d2, mu_s, mu_k (the user rig)."""
    if "k0" not in model.param_names:
        return ("k2", "d2", "mu_s", "mu_k")
    names = ["k0", "c0"] + (["k1"] if "k1" in model.param_names else [])
    law = model.law(model.spec.contacts[0].name)
    refs = dict(model.spec.contacts[0].params)
    for role in ("kinetic", "static"):
        n = law.with_role(role)
        if n and refs[n].kind == "param":
            names.append(refs[n].name)
    return tuple(names[:6])


def case(name: str, rig: ZooRig | Path) -> Case:
    """The identification case of a zoo rig (or a rig file)."""
    if isinstance(rig, ZooRig):
        path = Path(tempfile.mkdtemp(prefix="zoo_")) / "rig.toml"
        path.write_text(rig.text)
        describe = rig.describe()
    else:
        m = get_model(str(rig))
        return Case(name, m, m.published(), free_parameters(m), None,
                    f"user rig {rig.name}: 50 rpm, 150 rpm for the last third; CLI defaults (guess from the data, "
                    f"encoder zero free, hold-out 0.2)", encoder_zero="free", holdout=0.2, speed_up=3.0)
    m = get_model(str(path))
    truth = m.published()
    free = free_parameters(m)
    start = truth.replace(**{n: 1.2 * truth[n] for n in free})
    return Case(name, m, truth, free, start, describe)


def cases(examples: int = 6, user: bool = True) -> list[Case]:
    out = [case(n, z) for n, z in zoo(examples).items()]
    if user:
        out.append(case("user_pin_rig", USER_RIG))
    return out


def errors_in_bars(fit, truth) -> dict:
    """``{name: |estimate - truth| / total error}`` (the stated error ``fit.error``)."""
    return {n: abs(v - truth[n]) / e if e > 0 else math.inf for n, v, e in zip(fit.names, fit.estimate, fit.error)}


def rel_errors(fit, truth) -> dict:
    return {n: (v / truth[n] - 1) if truth[n] != 0 else float("nan") for n, v in zip(fit.names, fit.estimate)}


def finite(x) -> bool:
    return bool(np.isfinite(x))


if __name__ == "__main__":
    import argparse
    ap = argparse.ArgumentParser(description="Freeze the zoo's drawn rigs into benchmarks/zoo/ (as bench_identify_zoo "
                                             "draws them).", epilog="Example: python benchmarks/_zoo_rigs.py --freeze")
    ap.add_argument("--freeze", action="store_true", help="draw and write the rigs (overwrites benchmarks/zoo/)")
    if ap.parse_args().freeze:
        import bench_identify_zoo  # noqa: F401 - the benchmark's import state: the published tables' rigs
        freeze(draw_zoo())
        print(f"wrote {FROZEN}")
