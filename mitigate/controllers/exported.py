"""An exported controller library as a workbench controller (``kind = "exported"``): the artefact a
lab takes to its rig, compared on every scenario and in the benchmark like any other controller.

The library (``mitigate export``) runs its own estimator, so it must see every DAQ sample: the
closed loop calls :meth:`ExportedController.sample` at every sample (``own_estimator``), with the
controller enabled from ``[control] start``; :meth:`step` returns the library's action of that
sample.  The library is the folder ``mitigate export`` wrote (``path``); it is built with CMake the
first time if it has not been (:func:`mitigate.export.build_export`).  ``params`` overrides runtime
parameters by name (``{"rig:J1" = 0.03, "weight:speed" = 2.0}``: a refit needs no rebuild).
"""

from __future__ import annotations

import ctypes
import json
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Mapping

import numpy as np

from mitigate.controllers.base import Action, ControlContext, Controller
from models.checks import check_options, option, where_field
from models.errors import ConfigError
from models.status import Status

__all__ = ["ExportedController", "ExportedOptions", "ExportedLibrary"]


@dataclass(frozen=True, kw_only=True)
class ExportedOptions:
    """Options of ``kind = "exported"``.

    Parameters
    ----------
    path : the folder ``mitigate export`` wrote (relative to the working folder)
    params : runtime parameters by name (the library's ``params[]`` names) [their units]; the rest
        keep the exported defaults
    """

    path: str = option("", what="the folder `mitigate export` wrote", nonempty=True)
    params: Mapping[str, float] | None = option(None, by_name=True, none=True)
    where: str = where_field("exported")

    def __post_init__(self):
        check_options(self)


class ExportedLibrary:
    """The C API of an exported folder through ctypes: ``create``, ``step``, ``reset``, the layout.

    Raises
    ------
    ConfigError : not an export folder, or a parameter it does not have / not finite.
    """

    def __init__(self, path, params: Mapping[str, float] | None = None, where: str = "exported"):
        from mitigate.export import build_export
        folder = Path(path)
        man = folder / "export.json"
        if not man.is_file():
            raise ConfigError(f"{where}.path: {folder} is not a folder written by `mitigate export` (no export.json)")
        self.manifest = json.loads(man.read_text())
        p = self.manifest["prefix"]
        so = next((c for c in (folder / "build" / f"lib{p}.so", folder / f"lib{p}.so") if c.is_file()), None)
        if so is None:
            so = build_export(folder)
        self.library = so
        lib = self._lib = ctypes.CDLL(str(so))
        self._create, self._step = getattr(lib, f"{p}_create"), getattr(lib, f"{p}_step")
        self._create.restype = ctypes.c_void_p
        self._create.argtypes = [ctypes.c_void_p]
        self._step.restype = ctypes.c_int
        self._step.argtypes = [ctypes.c_void_p, ctypes.c_double, ctypes.c_void_p, ctypes.c_void_p]
        for name in ("reset", "destroy"):
            getattr(lib, f"{p}_{name}").argtypes = [ctypes.c_void_p]
        self._solve = getattr(lib, f"{p}_last_solve_time")
        self._step_time = getattr(lib, f"{p}_last_step_time")
        for f in (self._solve, self._step_time):
            f.restype = ctypes.c_double
            f.argtypes = [ctypes.c_void_p]
        self._prefix = p
        self.inputs = tuple(self.manifest["inputs"])
        self.outputs = tuple(self.manifest["outputs"])
        names = list(self.manifest["params"])
        values = np.array([float(v) for v in self.manifest["params"].values()])
        for k, v in (params or {}).items():
            if k not in names:
                raise ConfigError(f"{where}.params: the library has no parameter {k!r} (it has: {', '.join(names)})")
            if not isinstance(v, (int, float)) or isinstance(v, bool) or not math.isfinite(v):
                raise ConfigError(f"{where}.params.{k} must be a finite number, got {v!r}")
            values[names.index(k)] = float(v)
        self.params = values
        self._s = self._create(values.ctypes.data)
        if not self._s:
            raise ConfigError(f"{where}: the library's create() refused its parameters")
        self.in_buf = np.zeros(len(self.inputs))
        self.out_buf = np.zeros(len(self.outputs))

    def step(self, t: float) -> int:
        """One DAQ period with :attr:`in_buf`; the outputs are in :attr:`out_buf`."""
        return self._step(self._s, float(t), self.in_buf.ctypes.data, self.out_buf.ctypes.data)

    def reset(self) -> None:
        getattr(self._lib, f"{self._prefix}_reset")(self._s)

    @property
    def last_solve_time(self) -> float:
        """The controller's last solve [s], timed inside the library (a law: its call)."""
        return float(self._solve(self._s))

    @property
    def last_step_time(self) -> float:
        """The last whole step [s] (the estimator's update and the controller), timed inside the library."""
        return float(self._step_time(self._s))

    def __del__(self):
        s = getattr(self, "_s", None)
        if s:
            getattr(self._lib, f"{self._prefix}_destroy")(s)
            self._s = None


class ExportedController(Controller):
    """An exported controller library in the closed loop (module docstring)."""

    kind = "exported"
    options_class = ExportedOptions
    #: the library estimates the state itself from every DAQ sample (:meth:`sample`)
    own_estimator = True

    def __init__(self, options: ExportedOptions, context: ControlContext):
        super().__init__(options, context)
        m = context.model
        self.lib = lib = ExportedLibrary(options.path, options.params or {}, options.where)
        man = lib.manifest
        if man["rig"] != m.name:
            raise ConfigError(f"{options.where}.path: the library was exported for rig {man['rig']!r}, the scenario's "
                              f"is {m.name!r}")
        if abs(float(man["dt"]) - float(context.dt)) > 1e-12:
            raise ConfigError(f"{options.where}.path: the library runs at a DAQ period of {man['dt']} s, the scenario's "
                              f"is {context.dt} s")
        if abs(int(man["every"]) * float(man["dt"]) - float(context.period)) > 1e-12:
            raise ConfigError(f"{options.where}.path: the library's controller runs every {man['every']} DAQ period(s), "
                              f"the scenario's every {round(context.period / context.dt)}")
        self.commands = tuple(n for n in lib.outputs if not n.startswith("estimate:"))
        bad = [n for n in self.commands if n not in m.commands]
        if bad:
            raise ConfigError(f"{options.where}.path: the library commands {bad}, which rig {m.name!r} cannot set")
        self._prog = [(i, m.inputs.index(n.partition(":")[2])) for i, n in enumerate(lib.inputs)
                      if n.startswith("programme:")]
        self._chans = [(i, n) for i, n in enumerate(lib.inputs)
                       if not n.startswith("programme:") and n not in ("target_speed", "enable")]
        self._target = lib.inputs.index("target_speed") if "target_speed" in lib.inputs else None
        self._enable = lib.inputs.index("enable")
        self._last = None

    def actuated_inputs(self) -> tuple[str, ...]:
        return self.commands

    def reset(self) -> None:
        self.lib.reset()
        self._last = None

    def sample(self, t: float, measurement: Mapping[str, float], active: bool) -> None:
        """One DAQ sample through the library (estimator always; controller while ``active``)."""
        buf, ctx = self.lib.in_buf, self.context
        for i, ch in self._chans:
            v = measurement.get(ch) if measurement is not None else None
            buf[i] = float(v) if v is not None else math.nan
        u = ctx.programme(t)
        for i, j in self._prog:
            buf[i] = u[j]
        if self._target is not None:
            buf[self._target] = ctx.target_speed(t)
        buf[self._enable] = 1.0 if active else 0.0
        self._last = (t, self.lib.step(t))

    def _step_impl(self, t: float, measurement: Mapping[str, float], estimate) -> Action:
        if self._last is None or self._last[0] != t:
            raise ConfigError(f"{self.options.where}: an exported controller needs the closed loop's sample() at "
                              f"every DAQ sample (own_estimator)")
        status = self._last[1]
        out = self.lib.out_buf
        if status == 3:
            return Action({}, Status.FALLBACK, "the exported step failed (a non-finite output): the programme")
        u = {n: float(out[k]) for k, n in enumerate(self.commands)}
        st = {0: Status.OK, 1: Status.HOLD, 2: Status.FALLBACK}.get(status, Status.FALLBACK)
        return Action(u, st, {0: "exported step", 1: "hold", 2: "exported step: fallback"}.get(status, ""))
