"""The workbench's plant behind a UDP socket, for the exported controller's real-time driver
(``rt/driver.c`` of an export folder) running in another process.

The server is the scenario's plant as the closed loop builds it (:class:`models.plant.Plant` with the
scenario's true parameters, sensors, servos and drift), stepped in LOCKSTEP with the driver: each
command datagram (the library's commands for sample ``k``) holds the programme, with the commanded
inputs replaced, over one DAQ period, and the answer is sample ``k + 1`` as the library's ``in[]``
(the DAQ channels, the programme's values, the target speed, ``enable`` from the scenario's
``[control] start``).  It is :func:`mitigate.closedloop.run_closed_loop`'s sample loop with the
library in another process, so a run reproduces the workbench's own run sample by sample; the
driver's timing shows in its deadline statistics, not in the physics.

Wire format (host byte order, one machine): a 24-byte header ``magic "SSRT", kind, seq (u64), n, 0``
then ``n`` doubles (an error: ``n`` bytes of text); kinds 1 hello ``{n_in, n_cmd, dt}``, 2 command,
3 bye, 4 sample ``{t, in[]}``, 5 error.

Usage::

    python -m mitigate.export.rt SCENARIO.toml EXPORT_DIR --port 47100      # then the driver
    python -m mitigate.export.rt SCENARIO.toml EXPORT_DIR --run 30         # both, one command
"""

from __future__ import annotations

import json
import math
import socket
import struct
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from models.errors import ConfigError
from models.plant import Plant
from models.status import Status

__all__ = ["PlantServer", "PlantReport", "MAGIC", "HEADER"]

MAGIC = 0x54525353
#: magic, kind, seq, n, reserved
HEADER = struct.Struct("=IIQII")
HELLO, COMMAND, BYE, SAMPLE, ERROR = 1, 2, 3, 4, 5


@dataclass(frozen=True)
class PlantReport:
    """What the plant saw of a real-time run.

    Attributes
    ----------
    status : Status.OK; Status.DIVERGED (the plant left its bounds) or Status.FAILED (its step
        raised, or the driver stopped before its bye); message : why, one line
    samples : DAQ samples the plant was stepped; duration : their span [s]
    control_start : when ``enable`` went to 1 [s]
    window : the severity window, the rig's stick-slip period [s] (:func:`mitigate.metrics.rig_period`)
    severity_before : the objective body's TRUE speed's stick-slip severity over the window before
        ``control_start`` (NaN if the run did not cover it) [-]
    severity_last : the same over the run's last window [-]; mean_speed_last : its mean [rad/s]
    t : (m,) sample times [s]; inputs : (m, n_in) the in[] rows sent; commands : (m - 1, n_cmd) the
        commands received; speed : (m,) the objective body's true speed [rad/s]
    """

    status: Status
    message: str
    samples: int
    duration: float
    control_start: float
    window: float
    severity_before: float
    severity_last: float
    mean_speed_last: float
    t: np.ndarray
    inputs: np.ndarray
    commands: np.ndarray
    speed: np.ndarray

    @property
    def success(self) -> bool:
        return self.status.success

    def summary(self) -> dict:
        out = {k: getattr(self, k) for k in ("message", "samples", "duration", "control_start", "window",
                                              "severity_before", "severity_last", "mean_speed_last")}
        return {"status": self.status.value, **out}


class PlantServer:
    """The scenario's plant answering an exported controller's driver (module docstring).

    Parameters
    ----------
    scenario : a :class:`mitigate.scenario.Scenario` or the path of a scenario file
    export : the folder ``mitigate export`` wrote for that scenario
    host, port : where to listen (port 0: any free port, see :attr:`port`)
    timeout : seconds to wait for the next datagram before giving up [s]

    Raises
    ------
    ConfigError : not an export folder, or one exported for another rig or DAQ period.
    """

    def __init__(self, scenario, export, *, host: str = "127.0.0.1", port: int = 0, timeout: float = 30.0):
        from mitigate.scenario import Scenario, load_scenario
        self.scenario = sc = scenario if isinstance(scenario, Scenario) else load_scenario(scenario)
        man_path = Path(export) / "export.json"
        if not man_path.is_file():
            raise ConfigError(f"plant server: {export} is not a folder written by `mitigate export` (no export.json)")
        man = json.loads(man_path.read_text())
        if man["rig"] != sc.model.name or abs(float(man["dt"]) - sc.dt) > 1e-12:
            raise ConfigError(f"plant server: {export} was exported for rig {man['rig']!r} at {man['dt']} s, the "
                              f"scenario is rig {sc.model.name!r} at {sc.dt} s")
        self.in_names = list(man["inputs"])
        self.cmd_names = [n for n in man["outputs"] if not n.startswith("estimate:")]
        bad = [n for n in self.cmd_names if n not in sc.model.inputs]
        if bad:
            raise ConfigError(f"plant server: the export commands {bad}, which rig {sc.model.name!r} does not have")
        self._cmd_index = [sc.model.inputs.index(n) for n in self.cmd_names]
        self.k_start = int(math.ceil(sc.control.start / sc.dt - 1e-9))
        self.timeout = float(timeout)
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        try:
            self.sock.bind((host, int(port)))
        except OSError as exc:
            self.sock.close()
            raise ConfigError(f"plant server: cannot listen on {host}:{port}: {exc.strerror}") from None
        self.host, self.port = self.sock.getsockname()
        self._reset()

    def _reset(self) -> None:
        sc = self.scenario
        self.plant = Plant(sc.plant_model, sc.plant_params, sc.sim, sensors=sc.sensors, u0=sc.programme(0.0),
                           drift=sc.drift)
        self._speed_index = sc.plant_model.speed_index(sc.model.objective_body)
        self.k = 0
        self.rows, self.cmds, self.speed = [], [], []
        self._sample(self.plant.measure())

    def _sample(self, y: dict) -> list[float]:
        """in[] of sample ``self.k`` from the DAQ reading ``y`` (the layout of mitigate.export.interface)."""
        sc, t = self.scenario, self.k * self.scenario.dt
        prog = sc.programme(t)
        row = []
        for name in self.in_names:
            if name.startswith("programme:"):
                row.append(float(prog[sc.model.inputs.index(name.partition(":")[2])]))
            elif name == "target_speed":
                row.append(float(sc.control.speed(t)) if sc.control.speed is not None else sc.model.nominal_speed())
            elif name == "enable":
                row.append(1.0 if self.k >= self.k_start else 0.0)
            else:
                v = y.get(name)
                row.append(float(v) if v is not None else math.nan)
        self.rows.append(row)
        self.speed.append(float(self.plant.x[self._speed_index]))
        return row

    def _send(self, addr, kind: int, seq: int, values=()) -> None:
        data = np.asarray(values, dtype=float).tobytes()
        self.sock.sendto(HEADER.pack(MAGIC, kind, seq, len(values), 0) + data, addr)

    def _error(self, addr, seq: int, text: str) -> None:
        b = text.encode()[:1000]
        self.sock.sendto(HEADER.pack(MAGIC, ERROR, seq, len(b), 0) + b, addr)

    def serve(self) -> PlantReport:
        """Answer one driver from its hello to its bye; return what the plant saw."""
        sc = self.scenario
        status, message = Status.OK, "ok"
        self.sock.settimeout(self.timeout)
        started = False
        while True:
            try:
                data, addr = self.sock.recvfrom(65536)
            except socket.timeout:
                status, message = Status.FAILED, f"no datagram for {self.timeout:g} s after sample {self.k}: " \
                                                 f"the driver stopped"
                break
            if len(data) < HEADER.size:
                continue
            magic, kind, seq, n, _ = HEADER.unpack_from(data)
            if magic != MAGIC:
                continue
            values = np.frombuffer(data, dtype=float, count=n, offset=HEADER.size) if kind != ERROR else None
            if kind == HELLO:
                want = (len(self.in_names), len(self.cmd_names), sc.dt)
                if n != 3 or tuple(values) != (float(want[0]), float(want[1]), want[2]):
                    self._error(addr, seq, f"the driver's layout (in, commands, dt) = {tuple(values)}, the export's "
                                           f"{want}: a driver of another export")
                    continue
                if started:
                    self._reset()
                started = True
                self._send(addr, SAMPLE, 0, [0.0] + self.rows[0])
            elif kind == COMMAND and started:
                if seq != self.k or n != len(self.cmd_names):
                    self._error(addr, seq, f"command for sample {seq} with {n} values; the plant is at sample "
                                           f"{self.k} and takes {len(self.cmd_names)}")
                    continue
                u = sc.programme(self.k * sc.dt)
                u[self._cmd_index] = values
                self.cmds.append(np.array(values))
                try:
                    y = self.plant.step(u)
                except Exception as exc:  # noqa: BLE001 - the plant's failure ends the run with its reason
                    status, message = Status.FAILED, f"plant step failed at t = {(self.k + 1) * sc.dt:.3f} s: " \
                                                     f"{type(exc).__name__}: {exc}"
                    self._error(addr, seq, message)
                    break
                self.k += 1
                row = self._sample(y)
                if not np.all(np.isfinite(self.plant.x)) or abs(self.speed[-1]) > sc.max_speed:
                    status, message = Status.DIVERGED, f"the plant diverged at t = {self.k * sc.dt:.3f} s"
                    self._error(addr, seq, message)
                    break
                self._send(addr, SAMPLE, self.k, [self.k * sc.dt] + row)
            elif kind == BYE:
                break
        return self._report(status, message)

    def _report(self, status: Status, message: str) -> PlantReport:
        from mitigate.metrics import rig_period
        from mitigate.severity import severity
        sc = self.scenario
        w = np.array(self.speed)
        window = rig_period(sc.model, sc.model_params)
        nw = max(1, int(round(window / sc.dt)))
        before = w[self.k_start - nw:self.k_start + 1] if self.k_start >= nw and len(w) > self.k_start else None
        last = w[-nw - 1:]
        return PlantReport(status, message, self.k, self.k * sc.dt, self.k_start * sc.dt, window,
                           severity(before) if before is not None else math.nan, severity(last),
                           float(np.mean(last)), np.arange(len(w)) * sc.dt, np.array(self.rows),
                           np.array(self.cmds).reshape(-1, len(self.cmd_names)), w)

    def write_log(self, path, report: PlantReport) -> None:
        """CSV of the run: t, in[] (the library's names), the commands (``command:<input>``), the true speed."""
        n = len(report.t)
        cmds = np.vstack([report.commands, np.full((n - len(report.commands), len(self.cmd_names)), np.nan)])
        data = np.column_stack([report.t, report.inputs, cmds, report.speed])
        head = ",".join(["t"] + self.in_names + [f"command:{c}" for c in self.cmd_names] +
                        [f"true_omega_{self.scenario.model.objective_body}"])
        np.savetxt(path, data, delimiter=",", header=head, comments="", fmt="%.17g")

    def close(self) -> None:
        self.sock.close()
