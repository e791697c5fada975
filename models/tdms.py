"""LabView TDMS logs, read through npTDMS (an optional extra) into the one log format.

A small TOML mapping names, for each channel of the workbench vocabulary
(the rig's sensor and input channels), the TDMS group and channel it comes from and the
unit it was recorded in; time comes from a time channel or from the waveform increment::

    [time]                         # either a channel ...
    group = "Time"
    channel = "t"
    unit = "s"
    # ... or the waveform properties of the channels:  [time]  wf_increment = true
    # (t = wf_start_offset + k * wf_increment of the first mapped channel;
    #  an explicit  increment = 0.01  [s] overrides a missing property)

    [channels]
    omega1 = { group = "Encoders", channel = "Disc1 speed", unit = "rpm" }
    n1     = { group = "Load cells", channel = "Pin 1", unit = "kN" }

Units are converted as in the CSV format; the result is validated exactly like a CSV log
(finite values, strictly increasing time, no gaps) and speeds are derived from angles
where missing.
"""

from __future__ import annotations

import math
import os
from pathlib import Path

import numpy as np

from models.errors import ConfigError, DataError
from models.checks import read_toml
import re

from models.logs import Log, convert_unit

__all__ = ["read_tdms", "load_mapping"]


def _need_nptdms():
    try:
        import nptdms  # noqa: F401
    except ImportError:
        raise ConfigError("reading TDMS needs the optional package npTDMS (pip install npTDMS)") from None
    return nptdms


def load_mapping(path: str | os.PathLike) -> dict:
    """Read and check a TDMS channel mapping (see module docstring)."""
    path = Path(path)
    data = read_toml(path, "mapping file")
    for key in data:
        if key not in ("time", "channels"):
            raise ConfigError(f"{path}: unknown key {key!r}; expected 'time' and 'channels'")
    chans = data.get("channels")
    if not isinstance(chans, dict) or not chans:
        raise ConfigError(f"{path}: [channels] must map at least one vocabulary name to a TDMS channel")
    for name, spec in chans.items():
        if name == "t" or not re.match(r"^[A-Za-z_][A-Za-z0-9_]*$", name):
            raise ConfigError(f"{path}: channels.{name}: expected a log channel name (an identifier other than 't')")
        if not isinstance(spec, dict):
            raise ConfigError(f"{path}: channels.{name} must be a table {{group, channel, unit}}, got {spec!r}")
        for k in ("group", "channel", "unit"):
            if not isinstance(spec.get(k), str):
                raise ConfigError(f"{path}: channels.{name}.{k} must be a string, got {spec.get(k)!r}")
        extra = set(spec) - {"group", "channel", "unit"}
        if extra:
            raise ConfigError(f"{path}: channels.{name}: unknown key(s) {sorted(extra)}")
        try:
            convert_unit(name, spec["unit"], f"{path}: channels.{name}")
        except DataError as exc:
            raise ConfigError(str(exc)) from None
    tm = data.get("time")
    if not isinstance(tm, dict):
        raise ConfigError(f"{path}: [time] must give either group/channel/unit or wf_increment = true")
    if "channel" in tm:
        for k in ("group", "channel", "unit"):
            if not isinstance(tm.get(k), str):
                raise ConfigError(f"{path}: time.{k} must be a string, got {tm.get(k)!r}")
        try:
            convert_unit("t", tm["unit"], f"{path}: time")
        except DataError as exc:
            raise ConfigError(str(exc)) from None
    elif tm.get("wf_increment") is not True:
        raise ConfigError(f"{path}: [time] must give group/channel/unit of a time channel or wf_increment = true")
    inc = tm.get("increment")
    if inc is not None and not (isinstance(inc, (int, float)) and math.isfinite(inc) and inc > 0):
        raise ConfigError(f"{path}: time.increment must be a number > 0 s, got {inc!r}")
    return data


def _channel(f, group: str, channel: str, src: str):
    try:
        return f[group][channel]
    except KeyError:
        groups = [g.name for g in f.groups()]
        if group not in groups:
            raise DataError(f"{src}: no TDMS group {group!r} (groups: {', '.join(groups) or 'none'})") from None
        names = [c.name for c in f[group].channels()]
        raise DataError(f"{src}: no channel {channel!r} in group {group!r} (channels: {', '.join(names)})") from None


def read_tdms(path: str | os.PathLike, mapping_path: str | os.PathLike, required=()) -> Log:
    """Read a TDMS file into a validated :class:`models.logs.Log` via a channel mapping.

    Raises
    ------
    ConfigError : npTDMS missing, or a malformed mapping
    DataError : a mapped group/channel missing, lengths differ, or the data fail validation
    """
    nptdms = _need_nptdms()
    mapping = load_mapping(mapping_path)
    path = Path(path)
    src = str(path)
    try:
        f = nptdms.TdmsFile.read(str(path))
    except FileNotFoundError:
        raise DataError(f"{src}: log file not found") from None
    except Exception as exc:  # noqa: BLE001 - npTDMS raises various types on corrupt files
        raise DataError(f"{src}: not a readable TDMS file ({type(exc).__name__}: {exc})") from None
    if not list(f.groups()):
        raise DataError(f"{src}: not a readable TDMS file (no groups: empty or not TDMS)")
    chans = {}
    units = {}
    first = None
    for name, spec in mapping["channels"].items():
        ch = _channel(f, spec["group"], spec["channel"], src)
        first = first or ch
        units[name], factor = convert_unit(name, spec["unit"], f"{src}: {spec['group']}/{spec['channel']}")
        chans[name] = np.asarray(ch[:], dtype=float) * factor
    n = len(next(iter(chans.values())))
    for name, v in chans.items():
        if len(v) != n:
            raise DataError(f"{src}: channel {name!r} has {len(v)} samples, expected {n} like the others")
    tm = mapping["time"]
    if "channel" in tm:
        ch = _channel(f, tm["group"], tm["channel"], src)
        t = np.asarray(ch[:], dtype=float) * convert_unit("t", tm["unit"], f"{src}: time")[1]
        if len(t) != n:
            raise DataError(f"{src}: time channel has {len(t)} samples, expected {n}")
    else:
        props = first.properties
        inc = tm.get("increment", props.get("wf_increment"))
        if inc is None or not float(inc) > 0:
            raise DataError(f"{src}: channel {first.name!r} has no wf_increment property; "
                            f"give time.increment in the mapping or a time channel")
        t0 = float(props.get("wf_start_offset", 0.0))
        t = t0 + np.arange(n) * float(inc)
    log = Log(t, chans, src, (), units).with_speeds()
    log.require(required)
    return log
