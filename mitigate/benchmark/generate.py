"""The generalisation set: scenarios nobody tuned on, generated from a seed.

``mitigate benchmark SUITE --generated N --seed S`` replaces the suite's scenarios by N scenarios
drawn from S, written as files (a rig file and a scenario file each, and a suite file that lists them
with the suite's controllers, metrics and compute model) under ``DIR/generated/``, then benchmarks
them.  The same N and S give the same files on any machine (:func:`generate`): the values computed
with LAPACK or a root finder (the period, the operating point) are rounded to 12 digits first.

Each scenario is drawn, from ``numpy.random.default_rng([S, k, attempt])``:

- a rig of the rig zoo (:func:`models.rig.zoo.zoo_rig`): 1-4 bodies in a chain or a tree, an inertia
  scale from 10^-2 to 10 kg m^2, a DC-motor drive, a Stribeck or bit-rock contact on a leaf body with a
  servo on its normal force, and every sensor (encoders on the contact body and the drive, the drive's
  torque, the contact's load cell) -- what every controller of the suite can run on;
- an operating point: the programmed speed a fraction (:data:`SPEED_FRACTION`) of the rig's nominal
  speed, inside the laws' weakening range, where a start from rest sticks and slips, and the normal
  force a factor (:data:`FORCE_FACTOR`) of the operating point's that holds that speed;
- a mismatch: every stiffness and inertia of the plant and its friction level off the controllers'
  model by a factor each (:data:`MISMATCH`);
- the timing: DAQ period T/100 of the rig's stick-slip period T (its lowest mode with the drive held),
  control from 6 T, 14 T controlled.

A draw whose uncontrolled run does not stick and slip at the switch-on is replaced by the next
attempt (at most :data:`ATTEMPTS`).  At these low speeds the programme alone often leaves the body
stuck for most of the scored window (the seed-1 set: 24 of 30 runs of PI), where no drive-only
controller can do the job.  ``slipping=True`` (``--slipping``) also replaces a draw whose
uncontrolled run stalls (stuck for more than the suite's ``stuck_limit`` of its residual window,
the metrics' ``stalled`` on the programme alone), with up to :data:`SLIPPING_ATTEMPTS` draws: a set
on which every class can do the job.
"""

from __future__ import annotations

import json
import re
from pathlib import Path
from typing import Any, Mapping

import numpy as np

from models.checks import read_toml
from models.errors import ConfigError

__all__ = ["generate", "SPEED_FRACTION", "FORCE_FACTOR", "MISMATCH", "ATTEMPTS", "SLIPPING_ATTEMPTS"]

#: the programmed speed over the rig's nominal speed (the zoo's stick-slip programme is 0.1)
SPEED_FRACTION = (0.07, 0.15)
#: the normal force over the operating point's at that speed
FORCE_FACTOR = (0.8, 1.25)
#: the plant's stiffness, inertia and friction-level factors against the model's
MISMATCH = (0.8, 1.2)
#: draws per scenario before giving up
ATTEMPTS = 12
#: the same with ``slipping`` (most low-speed draws stall: about 4 in 5 of the seed-1 set's runs)
SLIPPING_ATTEMPTS = 40
#: the friction level's parameters of the laws a generated rig uses
_LEVEL = {"stribeck": ("mu_s", "mu_k"), "bit_rock": ("mu_sb", "mu_cb")}
_PERIODS_BEFORE, _PERIODS_CONTROLLED, _SAMPLES_PER_PERIOD = 6, 14, 100


def _toml(v: Any) -> str:
    """A TOML value (strings, numbers, booleans, lists and inline tables: what a suite holds)."""
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, (int, float)):
        return repr(v) if isinstance(v, int) else repr(float(v))
    if isinstance(v, str):
        return json.dumps(v)
    if isinstance(v, (list, tuple)):
        return "[" + ", ".join(_toml(x) for x in v) + "]"
    if isinstance(v, Mapping):
        return "{ " + ", ".join(f"{k} = {_toml(x)}" for k, x in v.items()) + " }"
    raise ConfigError(f"cannot write {v!r} ({type(v).__name__}) to a generated suite file")


def _portable(x: float) -> float:
    """``x`` to 12 significant digits.  The period (an eigenvalue) and the operating point (a root) come
    from LAPACK and scipy, whose last bits depend on the CPU's kernels (two x86_64 hosts with the same
    packages gave periods 2 ulp apart, and so different files); every value derived from them is
    written from the rounded one, so the same N and S give the same files on either."""
    return float(f"{float(x):.12g}")


def _draw(k: int, seed: int, attempt: int, where: Path) -> tuple[str, str, dict]:
    """(rig text, scenario text, what was drawn) of scenario ``k``."""
    from mitigate.metrics import rig_period
    from models import get_model
    from models.modal import operating_point
    from models.rig.zoo import SeededDraw, zoo_rig

    rng = np.random.default_rng([int(seed) & 0xFFFFFFFF, k, attempt])
    z = zoo_rig(SeededDraw(rng), max_bodies=4, drives=("dc_motor",), log_scale=(-2.0, 1.0),
                laws=tuple(_LEVEL), drop_sensors=False, servo=True)
    name = f"gen_{seed}_{k}"
    rig_text = re.sub(r'^name = ".*"$', f'name = "{name}"', z.text, count=1, flags=re.M)
    rig_path = where / f"{name}_rig.toml"
    rig_path.write_text(rig_text)
    m = get_model(str(rig_path))
    p = m.published()
    frac = float(rng.uniform(*SPEED_FRACTION))
    force = float(rng.uniform(*FORCE_FACTOR))
    u, _ = operating_point(m, p, omega=frac * m.nominal_speed())
    inputs = {n: _portable(v) for n, v in zip(m.inputs, u)}
    inputs[z.normal_input] = _portable(inputs[z.normal_input] * force)
    mism = {}
    for i in range(z.n_bodies):
        mism[f"k{i}"] = float(rng.uniform(*MISMATCH))
        mism[f"J{i}"] = float(rng.uniform(*MISMATCH))
    level = float(rng.uniform(*MISMATCH))
    for q in _LEVEL[z.law]:
        mism[q] = level
    T = _portable(rig_period(m, p))
    dt = T / _SAMPLES_PER_PERIOD
    start = _PERIODS_BEFORE * T
    drawn = {"rig": z.describe(), "speed_fraction": frac, "force_factor": force, "friction_level": level,
             "period": T}
    text = "\n".join([
        "# generated by mitigate.benchmark.generate (do not edit: the seed makes it)",
        "[scenario]", f"name = {_toml(name)}",
        f"description = {_toml(f'generated {k} of seed {seed}: {z.describe()}; programme {frac:.3g} of the nominal speed, normal force x{force:.3g}, plant mismatch (stiffness, inertia, friction level {level:.3g})')}",
        f"model = {_toml(rig_path.name)}", f"duration = {_toml(start + _PERIODS_CONTROLLED * T)}",
        f"dt = {_toml(dt)}", f"seed = {_toml(int(rng.integers(1, 2**31 - 1)))}", "",
        "[inputs]"] + [f"{n} = {_toml(v)}" for n, v in inputs.items()] + [
        "", "[mismatch]                 # plant = nominal x factor"] + [f"{n} = {_toml(v)}" for n, v in mism.items()] + [
        "", "[control]", f"start = {_toml(start)}", "", "[estimator]", 'kind = "ekf"', "compile = false", ""])
    return rig_text, text, drawn


def _stalls(sc, ref, metrics) -> bool:
    """The programme alone leaves the objective body stuck for more than ``metrics.stuck_limit`` of
    its residual window (the metrics' ``stalled``, on the uncontrolled run ``ref``)."""
    from mitigate.metrics.quantities import programmed_speed, windows
    from mitigate.severity import stuck_fraction

    if ref.speed is None:
        return True
    dt = sc.dt
    end = int(round(sc.duration / dt)) + 1
    n_res = max(2, int(round(windows(metrics, ref.period, sc.duration - sc.control.start, dt)[0] / dt)))
    tail = ref.speed[max(0, end - n_res):end]
    scale = abs(float(np.nanmean(programmed_speed(sc, dt * np.arange(end - len(tail), end))))) or 1.0
    stuck = metrics.stuck_speed if metrics.stuck_speed is not None else 1e-3 * scale
    return stuck_fraction(tail, stuck) > metrics.stuck_limit


def generate(suite_path, n: int, seed: int, out, *, slipping: bool = False) -> Path:
    """Write ``n`` generated scenarios of ``seed`` (module docstring) and their suite file under
    ``out`` (the suite of ``suite_path``'s controllers, metrics, phases, seeds, compute model and
    version); returns the generated suite file.  ``slipping``: only draws whose uncontrolled run
    does not stall (module docstring).

    Raises
    ------
    ConfigError : a bad ``n`` or ``seed``, or no draw of a scenario sticks and slips (``slipping``: and
        keeps slipping) in :data:`ATTEMPTS` (:data:`SLIPPING_ATTEMPTS`).
    """
    from mitigate.benchmark.plan import reference_run
    from mitigate.benchmark.suite import load_suite
    from mitigate.scenario import load_scenario

    for name, v, lo in (("generated", n, 1), ("seed", seed, 0)):
        if isinstance(v, bool) or not isinstance(v, int) or v < lo:
            raise ConfigError(f"{name} must be an integer >= {lo}, got {v!r}")
    base = load_suite(suite_path)               # the suite must be valid before anything is drawn
    raw = read_toml(suite_path, "benchmark suite")
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    files, drawn = [], {}
    attempts = SLIPPING_ATTEMPTS if slipping else ATTEMPTS
    for k in range(n):
        for attempt in range(attempts):
            _rig, text, what = _draw(k, seed, attempt, out)
            path = out / f"gen_{seed}_{k}.toml"
            path.write_text(text)
            try:
                sc = load_scenario(path)
                ref = reference_run(sc, base.metrics)
            except ConfigError:
                continue
            if ref.stick_slip and not (slipping and _stalls(sc, ref, base.metrics)):
                files.append(path.name)
                drawn[path.stem] = {**what, "attempt": attempt}
                break
        else:
            what = "stuck and slipped at its switch-on" + (" without stalling" if slipping else "")
            raise ConfigError(f"generated scenario {k} of seed {seed}: no draw {what} in {attempts} attempts")
    s = raw.get("suite", {})
    key = {"n": n, "seed": seed, **({"slipping": True} if slipping else {})}
    lines = ["# generated by mitigate.benchmark.generate: " + json.dumps(key),
             "[suite]", f"name = {_toml(str(s.get('name', base.name)) + ('-generated-slipping' if slipping else '-generated'))}"]
    if base.version:
        lines.append(f"version = {_toml(base.version)}")
    kind = ", the programme alone not stalling" if slipping else ""
    plural = "s" if n != 1 else ""
    lines += [f"description = {_toml(f'{n} scenario{plural} generated from seed {seed} (rig zoo rigs, operating points, mismatches{kind}): nobody tuned on them')}",
              f"scenarios = {_toml(files)}", f"phases = {base.phases}", f"seeds = {base.seeds}",
              f"compute = {_toml(base.compute)}", "", "[metrics]"]
    lines += [f"{k} = {_toml(v)}" for k, v in raw.get("metrics", {}).items()]
    for c in raw.get("controllers", []):
        lines += ["", "[[controllers]]"] + [f"{k} = {_toml(v)}" for k, v in c.items()]
    suite_file = out / "suite.toml"
    suite_file.write_text("\n".join(lines) + "\n")
    (out / "generated.json").write_text(json.dumps({**key, "scenarios": drawn}, indent=2) + "\n")
    return suite_file
