"""TDMS logs through npTDMS with a TOML channel mapping (models.tdms)."""

import math
import textwrap

import numpy as np
import pytest

import nptdms
from nptdms import ChannelObject, TdmsWriter  # noqa: E402

from models.errors import ConfigError, DataError  # noqa: E402
from models import tdms  # noqa: E402
from models.tdms import read_tdms  # noqa: E402


def make_tdms(path, n=50, dt=0.01, with_time=True, bad_value=None):
    t = np.arange(n) * dt
    speed_rpm = 30 + np.sin(t)
    force_kn = np.full(n, 0.02)
    if bad_value is not None:
        speed_rpm[5] = bad_value
    props = {"wf_increment": dt, "wf_start_offset": 0.0}
    objs = [ChannelObject("Encoders", "Disc1 speed", speed_rpm, properties=props),
            ChannelObject("Load cells", "Pin 1", force_kn, properties=props)]
    if with_time:
        objs.append(ChannelObject("Time", "t", t * 1000.0))
    with TdmsWriter(str(path)) as w:
        w.write_segment(objs)
    return t, speed_rpm


def doc_mapping() -> str:
    """The example mapping of :mod:`models.tdms`'s docstring (the block after its ``::``)."""
    block = []
    for line in tdms.__doc__.split("::\n", 1)[1].splitlines():
        if line.strip() and not line.startswith("    "):
            break
        block.append(line)
    return textwrap.dedent("\n".join(block)).strip() + "\n"


#: the documented mapping, with the time channel in ms as make_tdms writes it
MAP_TIME = doc_mapping().replace('unit = "s"', 'unit = "ms"', 1)
MAP_WF = MAP_TIME.replace('group = "Time"\nchannel = "t"\nunit = "ms"', "wf_increment = true")


def test_read_with_time_channel(tmp_path):
    """The documented example mapping (models.tdms) reads a file: time in ms, speed in rpm, force in kN."""
    t, rpm = make_tdms(tmp_path / "a.tdms")
    (tmp_path / "m.toml").write_text(MAP_TIME)
    log = read_tdms(tmp_path / "a.tdms", tmp_path / "m.toml", required=("omega1", "n1"))
    np.testing.assert_allclose(log.t, t, atol=1e-12)
    np.testing.assert_allclose(log["omega1"], rpm * 2 * math.pi / 60)
    np.testing.assert_allclose(log["n1"], 20.0)


def test_read_with_waveform_increment(tmp_path):
    t, rpm = make_tdms(tmp_path / "a.tdms", with_time=False)
    (tmp_path / "m.toml").write_text(MAP_WF)
    log = read_tdms(tmp_path / "a.tdms", tmp_path / "m.toml")
    np.testing.assert_allclose(log.t, t, atol=1e-12)
    assert log.dt == pytest.approx(0.01)


def test_missing_channel_named(tmp_path):
    make_tdms(tmp_path / "a.tdms")
    (tmp_path / "m.toml").write_text(MAP_TIME.replace("Disc1 speed", "Disc9 speed"))
    with pytest.raises(DataError, match=r"no channel 'Disc9 speed' in group 'Encoders'"):
        read_tdms(tmp_path / "a.tdms", tmp_path / "m.toml")


def test_nan_in_tdms_rejected_like_csv(tmp_path):
    make_tdms(tmp_path / "a.tdms", bad_value=np.nan)
    (tmp_path / "m.toml").write_text(MAP_TIME)
    with pytest.raises(DataError, match=r"column 'omega1' row 6"):
        read_tdms(tmp_path / "a.tdms", tmp_path / "m.toml")


@pytest.mark.parametrize("bad, msg", [
    ("t = { group = \"a\", channel = \"b\", unit = \"s\" }", "channels.t: expected a log channel name"),
    ("omega2 = { group = \"a\", channel = \"b\", unit = \"furlong\" }", r"unit \[furlong\] cannot be converted"),
    ("omega2 = \"Encoders/Disc1\"", "must be a table"),
])
def test_bad_mapping(tmp_path, bad, msg):
    make_tdms(tmp_path / "a.tdms")
    (tmp_path / "m.toml").write_text(MAP_TIME + bad + "\n")
    with pytest.raises(ConfigError, match=msg):
        read_tdms(tmp_path / "a.tdms", tmp_path / "m.toml")


def test_not_a_tdms_file(tmp_path):
    (tmp_path / "a.tdms").write_text("hello")
    (tmp_path / "m.toml").write_text(MAP_TIME)
    with pytest.raises(DataError, match="not a readable TDMS file"):
        read_tdms(tmp_path / "a.tdms", tmp_path / "m.toml")


def test_missing_nptdms_is_a_config_error(tmp_path, monkeypatch):
    import builtins

    real = builtins.__import__

    def fake(name, *a, **k):
        if name == "nptdms":
            raise ImportError("no")
        return real(name, *a, **k)
    monkeypatch.setattr(builtins, "__import__", fake)
    with pytest.raises(ConfigError, match="needs the optional package npTDMS"):
        read_tdms(tmp_path / "a.tdms", tmp_path / "m.toml")
