"""A benchmark suite: its scenarios, the controllers compared on each, and how runs are scored.

A suite is a TOML file (``scenarios/benchmark/suite.toml``)::

    [suite]
    name = "stickslip-benchmark-2"
    scenarios = ["established.toml", "bistable.toml", ...]   # relative to the suite file
    phases = 6          # switch-on instants spread over one stick-slip period (reference results)
    seeds = 3           # noise seeds per switch-on instant
    deadline = "period" # each controller call's real-time budget ("off", "5 ms"; a scenario's own wins)

    [metrics]           # mitigate.metrics.MetricOptions, e.g. the programme's band of a normal force
    force_band = [0.8, 1.25]

    [[controllers]]     # run on every scenario (as a scenario's [[controllers]])
    name = "SoftSpeed"
    kind = "softspeed"

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
from mitigate.metrics import MetricOptions
from mitigate.scenario import ControllerSpec, Scenario, parse_scenario

__all__ = ["Suite", "load_suite", "controller_spec"]

_SUITE_KEYS = ("name", "description", "scenarios", "phases", "seeds", "deadline")


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
    """

    name: str
    description: str
    scenarios: tuple[Scenario, ...]
    controllers: tuple[ControllerSpec, ...]
    path: str = ""
    metrics: MetricOptions = MetricOptions()
    phases: int = 6
    seeds: int = 3

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
    # every controller call's real-time budget unless a scenario states its own ([control] deadline:
    # "period", "off" or a time); a late answer is a counted miss and the fallback acts -- a run with
    # misses depends on the machine's load (bit-reproducible only without)
    deadline = s.get("deadline", "period")
    if isinstance(deadline, bool) or not isinstance(deadline, (str, int, float)):
        raise ConfigError(f"{where}: suite.deadline must be \"period\", \"off\" or a time such as \"5 ms\", "
                          f"got {deadline!r}")
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
    scenarios = []
    for f in files:
        p = path.parent / f
        sd = dict(read_toml(p, "scenario file"))
        sd["controllers"] = raw_ctrls
        if isinstance(sd.get("control", {}), Mapping):     # a real-time budget (default one control period)
            sd["control"] = {"deadline": deadline, **sd.get("control", {})}
        scenarios.append(parse_scenario(sd, str(p)))
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
                 str(path), metrics, phases, seeds)
