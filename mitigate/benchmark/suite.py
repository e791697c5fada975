"""A benchmark suite: its scenarios, the controllers compared on each, and how runs are scored.

A suite is a TOML file (``scenarios/benchmark/suite.toml``)::

    [suite]
    name = "stickslip-benchmark"
    version = "1"       # the frozen suite's version (mitigate.benchmark.freeze)
    scenarios = ["established.toml", "bistable.toml", ...]   # relative to the suite file
    phases = 6          # switch-on instants spread over one stick-slip period (reference results)
    seeds = 3           # noise seeds per switch-on instant
    compute = "period"  # the compute model: each answer applied one control period late ("period"),
                        # or after a fixed latency ("2 ms", "0 s"); no deadline, so no wall clock

    [metrics]           # mitigate.metrics.MetricOptions, e.g. the programme's band of a normal force
    force_band = [0.8, 1.25]

    [[controllers]]     # run on every scenario (as a scenario's [[controllers]])
    name = "SoftSpeed"
    kind = "softspeed"

**The compute model.**  The ranked results never depend on the machine: every controller's answer
is applied ``compute`` late (one control period, or the suite's fixed latency) and no call has a
wall-clock deadline, so the same command gives the same numbers on any machine and at any load.  A
scenario that states its own ``[control] latency`` or ``deadline`` keeps it; one whose latency is
``"measured"`` (each answer applied after its own computation time: the suite's ``latency``) or that
has a deadline depends on the machine: it is a TIMING scenario (:attr:`Suite.timing`), reported apart
from the ranked results.

A scenario of the suite may list ``[[controllers]]`` of its own: they are replaced by the suite's.
A scenario whose control starts at t = 0 is a PREVENTION scenario (from rest, no stick-slip yet);
every other one is a SUPPRESSION scenario and must have stick-slip at its switch-on
(:mod:`mitigate.benchmark.plan` checks it on the uncontrolled run).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Mapping

from models.checks import options_from_mapping, read_toml
from models.errors import ConfigError
from mitigate.scenario_fields import MAX_CALL_TIME, si_value
from mitigate.metrics import MetricOptions
from mitigate.scenario import ControllerSpec, Scenario, parse_scenario

__all__ = ["Suite", "load_suite", "controller_spec", "compute_model"]

_SUITE_KEYS = ("name", "version", "description", "scenarios", "phases", "seeds", "compute")


@dataclass(frozen=True)
class Suite:
    """A benchmark suite.

    Attributes
    ----------
    name, description : from ``[suite]``
    scenarios : the scenarios, each with the suite's controllers
    controllers : the controllers compared
    metrics : :class:`mitigate.metrics.MetricOptions` of ``[metrics]`` (its ``period`` is set per
        scenario from the uncontrolled run)
    phases, seeds : the suite's defaults for the reference results
    path : the suite file
    version : ``[suite] version`` ("" for a suite that is not frozen)
    compute : the compute model as the suite states it ("period" or a latency such as "2 ms")
    timing : names of the TIMING scenarios (their results depend on the machine: module docstring)
    """

    name: str
    description: str
    scenarios: tuple[Scenario, ...]
    controllers: tuple[ControllerSpec, ...]
    path: str = ""
    metrics: MetricOptions = MetricOptions()
    phases: int = 6
    seeds: int = 3
    version: str = ""
    compute: str = "period"
    timing: tuple[str, ...] = ()

    @property
    def compute_text(self) -> str:
        """The compute model in words (the results and the leaderboard state it)."""
        when = "one control period" if self.compute == "period" else self.compute
        return (f"each controller answer applied {when} after the sample it was computed for; no wall-clock "
                f"deadline (results independent of the machine)")

    def scenario(self, name: str) -> Scenario:
        """The scenario called ``name``."""
        for sc in self.scenarios:
            if sc.name == name:
                return sc
        raise ConfigError(f"scenario {name!r} is not in the suite ({', '.join(s.name for s in self.scenarios)})")

    def controller(self, name: str) -> ControllerSpec:
        """The controller called ``name``."""
        for c in self.controllers:
            if c.name == name:
                return c
        raise ConfigError(f"controller {name!r} is not in the suite ({', '.join(c.name for c in self.controllers)})")


def controller_spec(c, where: str) -> ControllerSpec:
    """A ControllerSpec from a ``[[controllers]]`` table (or a ControllerSpec)."""
    if isinstance(c, ControllerSpec):
        return c
    if not isinstance(c, Mapping) or not isinstance(c.get("name"), str) or not isinstance(c.get("kind"), str):
        raise ConfigError(f"{where} must be a table with a name and a kind, got {c!r}")
    return ControllerSpec(c["name"], c["kind"], {k: v for k, v in c.items() if k not in ("name", "kind")})


def _count(v, where: str) -> int:
    if isinstance(v, bool) or not isinstance(v, int) or v < 1:
        raise ConfigError(f"{where} must be an integer >= 1, got {v!r}")
    return v


def _check_options(ctrls, where: str, n_suite: int) -> None:
    """A wrong kind or option is an error of the suite, found before anything runs; only what a
    scenario's rig lacks (a servo, a channel) makes a controller "not applicable" there."""
    from dataclasses import is_dataclass

    from mitigate.controllers.factory import controller_class, parse_options
    for i, c in enumerate(ctrls):
        cw = f"{where}: controllers[{i}]" if i < n_suite else f"controller {c.name!r}"
        cls = controller_class(c.kind, cw)
        oc = getattr(cls, "options_class", None)
        if oc is not None and is_dataclass(oc):
            parse_options(oc, dict(c.options), cw)


def load_suite(path, *, extra_controllers=(), only=None) -> Suite:
    """Read a suite file; ``extra_controllers`` (ControllerSpec or mappings) are added to its
    controllers, ``only`` restricts it to those scenario names.

    Raises
    ------
    ConfigError : one line naming the file and field of the first problem.
    """
    path = Path(path)
    data = read_toml(path, "benchmark suite")
    where = path.name
    for k in data:
        if k not in ("suite", "controllers", "metrics"):
            raise ConfigError(f"{where}: {k}: unknown section; expected suite, metrics and controllers")
    s = data.get("suite", {})
    if not isinstance(s, Mapping):
        raise ConfigError(f"{where}: suite must be a table")
    for k in s:
        if k not in _SUITE_KEYS:
            raise ConfigError(f"{where}: suite.{k}: unknown key; expected {', '.join(_SUITE_KEYS)}")
    files = s.get("scenarios")
    if not isinstance(files, list) or not files or not all(isinstance(f, str) for f in files):
        raise ConfigError(f"{where}: suite.scenarios must be a list of scenario files, got {files!r}")
    phases = _count(s.get("phases", 6), f"{where}: suite.phases")
    seeds = _count(s.get("seeds", 3), f"{where}: suite.seeds")
    compute = s.get("compute", "period")
    if compute != "period":
        try:
            ok = not isinstance(compute, bool) and 0 <= si_value(compute, "time", f"{where}: suite.compute") \
                <= MAX_CALL_TIME
        except ConfigError:
            ok = False
        if not ok:
            raise ConfigError(f"{where}: suite.compute must be \"period\" or a latency >= 0 such as \"2 ms\", "
                              f"got {compute!r}")
    version = s.get("version", "")
    if not isinstance(version, str):
        raise ConfigError(f"{where}: suite.version must be a string such as \"1\", got {version!r}")
    metrics = options_from_mapping(MetricOptions, data.get("metrics", {}), f"{where}: metrics")
    raw = data.get("controllers")
    if not isinstance(raw, list) or not raw:
        raise ConfigError(f"{where}: controllers: list at least one [[controllers]] table")
    ctrls: list[ControllerSpec] = []
    for i, c in enumerate(raw):
        spec = controller_spec(c, f"{where}: controllers[{i}]")
        if spec.name in [x.name for x in ctrls]:
            raise ConfigError(f"{where}: controllers[{i}].name: duplicate controller name {spec.name!r}")
        ctrls.append(spec)
    n_suite = len(ctrls)
    for c in extra_controllers:
        spec = controller_spec(c, "controller")
        if spec.name in [x.name for x in ctrls]:
            raise ConfigError(f"controller name {spec.name!r} is already in the suite")
        ctrls.append(spec)
    _check_options(ctrls, where, n_suite)
    raw_ctrls = [{"name": c.name, "kind": c.kind, **c.options} for c in ctrls]
    scenarios, timing = [], []
    for f in files:
        p = path.parent / f
        own = compute_model(read_toml(p, "scenario file"), str(p), compute)
        sc = parse_scenario({**own, "controllers": raw_ctrls}, str(p))
        scenarios.append(sc)
        ctl = own.get("control", {}) if isinstance(own.get("control", {}), Mapping) else {}
        if ctl.get("latency") == "measured" or ctl.get("deadline", "off") != "off":
            timing.append(sc.name)
    names = [sc.name for sc in scenarios]
    dup = next((n for n in names if names.count(n) > 1), None)
    if dup:
        raise ConfigError(f"{where}: suite.scenarios: two scenarios are named {dup!r}")
    if only:
        bad = [o for o in only if o not in names]
        if bad:
            raise ConfigError(f"scenario {bad[0]!r} is not in the suite ({', '.join(names)})")
        scenarios = [sc for sc in scenarios if sc.name in only]
    return Suite(str(s.get("name", path.stem)), str(s.get("description", "")), tuple(scenarios), tuple(ctrls),
                 str(path), metrics, phases, seeds, version, str(compute),
                 tuple(n for n in timing if n in {sc.name for sc in scenarios}))


def compute_model(data: Mapping, path: str, compute="period") -> dict:
    """A scenario's TOML table under the suite's compute model (module docstring): no deadline, and
    each answer applied ``compute`` late ("period": one control period of that scenario), unless the
    scenario states its own ``[control] latency`` or ``deadline``."""
    sd = dict(data)
    ctl = sd.get("control", {})
    if not isinstance(ctl, Mapping):
        return sd                          # parse_scenario names the error
    ctl = dict(ctl)
    ctl.setdefault("deadline", "off")
    if "latency" not in ctl:
        if compute == "period":
            sc = parse_scenario({**sd, "control": ctl, "controllers": []}, path)
            ctl["latency"] = sc.dt * sc.control.every
        else:
            ctl["latency"] = compute
    sd["control"] = ctl
    return sd
