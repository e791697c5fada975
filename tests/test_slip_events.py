"""The stick-slip period as slip events (models.signals.slip_events), not the spectrum's peak.

Issue 28: on a paper-on-paper slider whose slips came every 1.41-1.50 s the hold-out's "measured
stick-slip period" read 5.23 s and 7.41 s (the spectrum's peak of an irregular sawtooth), and a
steady-sliding hold-out printed a period that meant nothing.  Here: irregular sawtooths and speed
bursts with known slip times, found to within a few samples; sliding records give no period."""

import numpy as np
import pytest

from models.errors import ConfigError
from models.signals import period, slip_events, slip_period

DT = 0.0005          # the slider's 2 kHz


def irregular_slips(seed, duration=12.0, lo=1.41, hi=1.50):
    rng = np.random.default_rng(seed)
    t = [0.3]
    while t[-1] < duration - hi - 0.1:
        t.append(t[-1] + rng.uniform(lo, hi))
    return np.array(t)


def sawtooth(slips, duration=12.0, rate=1.0, slip_time=0.015, seed=0, noise=0.003):
    """A spring's force: a linear build-up, at each slip a drop (a quarter sine over ``slip_time``)
    of a random size between 0.6 and 1.2."""
    rng = np.random.default_rng(seed)
    t = np.arange(0.0, duration, DT)
    F = np.empty_like(t)
    f, j, i = 0.5, 0, 0
    n = int(round(slip_time / DT))
    while i < t.size:
        if j < slips.size and t[i] >= slips[j]:
            drop = rng.uniform(0.6, 1.2)
            seg = f - drop * np.sin(np.linspace(0, np.pi / 2, n))
            F[i:i + n] = seg[:t.size - i]
            f, i, j = f - drop, i + n, j + 1
            continue
        f += rate * DT
        F[i] = f
        i += 1
    return F + noise * rng.standard_normal(t.size)


def bursts(slips, duration=12.0, peak=3.0, slip_time=0.25, q=0.05, seed=0):
    """A sliding body's speed: at rest, at each slip a half-sine burst; quantised like an encoder's."""
    rng = np.random.default_rng(seed)
    t = np.arange(0.0, duration, DT)
    v = np.zeros_like(t)
    for s in slips:
        m = (t >= s) & (t < s + slip_time)
        v[m] = peak * np.sin(np.pi * (t[m] - s) / slip_time) * rng.uniform(0.7, 1.0)
    return np.round((v + 0.01 * rng.standard_normal(t.size)) / q) * q


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_an_irregular_sawtooth_gives_its_slips_and_their_period(seed):
    slips = irregular_slips(seed)
    F = sawtooth(slips, seed=seed)
    ev = slip_events(F, DT, "force")
    assert ev.times.size == slips.size
    np.testing.assert_allclose(ev.times, slips, atol=4 * DT)
    assert ev.period == pytest.approx(np.median(np.diff(slips)), rel=0.01)
    assert 1.41 <= ev.period <= 1.50 and ev.cycles == slips.size - 1
    # the spectrum's peak of the same record: what the hold-out used to print
    assert not 1.3 < period(F, DT) < 1.6
    # a spring loaded the other way: its slips are sharp rises
    assert slip_events(-F, DT, "force").period == pytest.approx(ev.period)


def test_fast_slips_at_another_spring():
    """The stiffer spring's 0.65 s slips (the issue's 2.79 s misreading)."""
    slips = irregular_slips(5, lo=0.62, hi=0.68)
    ev = slip_events(sawtooth(slips, rate=2.0, seed=5), DT, "force")
    np.testing.assert_allclose(ev.times, slips, atol=4 * DT)
    assert ev.period == pytest.approx(np.median(np.diff(slips)), rel=0.01)


@pytest.mark.parametrize("seed", [1, 4])
def test_speed_bursts_from_rest_give_their_onsets(seed):
    slips = irregular_slips(seed, lo=0.9, hi=1.4)
    ev = slip_events(bursts(slips, seed=seed), DT, "speed")
    assert ev.times.size == slips.size
    # onset: the last sample at rest (below a tenth of the peak) before the burst
    assert np.all(ev.times <= slips + 0.02) and np.all(ev.times >= slips - 2 * DT)
    assert ev.period == pytest.approx(np.median(np.diff(slips)), abs=0.02)
    assert slip_period(-bursts(slips, seed=seed), DT, "speed") == pytest.approx(ev.period)   # turning backwards


def test_steady_sliding_has_no_period():
    rng = np.random.default_rng(7)
    n = 8000
    force = 2.0 + 0.003 * rng.standard_normal(n)
    speed = 2.0 + 0.01 * rng.standard_normal(n)
    quantised = np.round((2.0 + 0.02 * rng.standard_normal(n)) / 0.05) * 0.05
    for x, kind in ((force, "force"), (speed, "speed"), (quantised, "speed"), (quantised, "force")):
        ev = slip_events(x, DT, kind)
        assert np.isnan(ev.period) and ev.cycles == 0, (kind, ev)
        assert "steady sliding" in ev.why
    # a speed oscillating about its sliding speed without stopping: no slips
    t = np.arange(n) * DT
    ev = slip_events(2.0 + 0.8 * np.sin(2 * np.pi * 2.0 * t), DT, "speed")
    assert np.isnan(ev.period) and "never comes to rest" in ev.why


def test_a_smooth_oscillation_is_not_a_sawtooth():
    t = np.arange(0.0, 12.0, DT)
    ev = slip_events(np.sin(2 * np.pi * 0.7 * t), DT, "force")
    assert np.isnan(ev.period) and "oscillation" in ev.why


def test_bad_arguments_are_one_line():
    with pytest.raises(ConfigError, match="kind must be one of speed, force, got 'twist'"):
        slip_events(np.zeros(10), 0.01, "twist")
    with pytest.raises(ConfigError, match="dt must be a number > 0 s"):
        slip_events(np.zeros(10), 0.0)
    assert np.isnan(slip_period(np.zeros(3), 0.01))


#: the slips of the measured paper-on-paper slider excerpts (tests/data/paper_slider: Colas et al., Phys. Rev.
#: E 100, 032803 (2019), CeCILL-B), read off their plots: every drop of the spring force of more than ~8 mN
#: (k = 1002 N/m; a 7 mN drop at 4.02 s is below the record's 15 noise levels) and of more than ~4 mN (168 N/m)
MEASURED_SLIPS = {"k1002Nm_v42": (0.59, 1.07, 1.69, 2.35, 3.23, 4.43, 4.98, 5.74, 7.04, 7.73),
                  "k168Nm_v42": (1.47, 4.96, 6.82, 9.36, 11.10, 11.92, 14.70)}


@pytest.mark.parametrize("record", sorted(MEASURED_SLIPS))
def test_the_slips_of_a_measured_force_with_spikes_and_quantisation(record):
    """The measured force holds impulsive spikes as large as its slips and a quantisation step of
    0.84 / 0.18 mN; its slips range over 10x in size.  Before: 139 slips in 8 s (k1002, period 0.043 s),
    327 in 16 s (k168).  Every slip is found, in the whole record and in each half alike."""
    from models.logs import read_csv
    from pathlib import Path
    log = read_csv(Path(__file__).parent / "data" / "paper_slider" / f"{record}.csv")
    x, t = np.asarray(log["torque_spring"]), np.asarray(log.t)
    dt = float(t[1] - t[0])
    expected = np.array(MEASURED_SLIPS[record])
    ev = slip_events(x, dt, "force")
    assert ev.times.size == expected.size and np.max(np.abs(ev.times - expected)) < 0.03, ev.times
    assert ev.period == pytest.approx(np.median(np.diff(expected)), abs=0.03)
    half = x.size // 2
    for part, t0 in ((x[:half], 0.0), (x[half:], half * dt)):
        got = slip_events(part, dt, "force").times + t0
        inside = expected[(expected > t0 + 0.05) & (expected < t0 + part.size * dt - 0.05)]
        assert got.size == inside.size and np.max(np.abs(got - inside)) < 0.03, (got, inside)
