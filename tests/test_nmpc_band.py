"""The NMPC's force band on the moving mean (mitigate/controllers/nmpc/band.py), checked by
simulating the servo sample by sample and averaging every window directly."""

import math
from types import SimpleNamespace

import numpy as np
import pytest

from models.actuators import Servo
from mitigate.controllers.nmpc.band import ForceHistory, window_bounds

DT = 0.01


def _windows(history, servo_spec, s0, c, n_look, w):
    """Every window's mean force over its programme's mean, the command ``c`` held (direct sums)."""
    f_old, p_old, p = history
    s = Servo(servo_spec, DT, s0)
    new = [s.step(c) for _ in range(n_look)]
    f = np.concatenate([f_old[::-1], new])          # oldest first
    pr = np.concatenate([p_old[::-1], np.full(n_look, p)])
    k0 = len(f_old)
    return np.array([f[k0 + j - w + 1:k0 + j + 1].sum() / pr[k0 + j - w + 1:k0 + j + 1].sum() for j in range(n_look)])


@pytest.mark.parametrize("seed", range(8))
def test_window_bounds_are_the_tightest_held_commands(seed):
    """At each end of the range, holding that command keeps every window's mean in the band, and a
    command a little beyond it does not (the range is tight), with the servo's lag and rate limit."""
    rng = np.random.default_rng(seed)
    w = int(rng.integers(20, 120))
    spec = SimpleNamespace(n_min=0.0, n_max=40.0, rate_max=float(rng.uniform(50, 400)), tau=float(rng.uniform(0, 0.08)))
    p = 10.0
    f_old = np.clip(10.0 + rng.normal(0, 4, w), 0, 40)        # the newest first
    p_old = np.full(w, p)
    band = (0.8, 1.25)
    # a past at the band's edge: scale it so that the window is near its low (or high) end
    f_old *= (0.82 if seed % 2 else 1.22) * p / f_old.mean()
    s0 = float(f_old[0])
    alpha = 1.0 - math.exp(-DT / spec.tau) if spec.tau > 0 else 1.0
    n_look = int(rng.integers(3, 40))
    lo, hi = window_bounds(f_old, p_old, s0, p, (0.0, 40.0, alpha, spec.rate_max * DT), n_look, band, 0.0, 40.0)
    assert 0.0 <= lo <= hi <= 40.0
    hist = (f_old, p_old, p)
    for c in (lo, hi):
        r = _windows(hist, spec, s0, c, n_look, w)
        assert r.min() >= band[0] - 1e-12 and r.max() <= band[1] + 1e-12
    if lo > 0.0:
        assert _windows(hist, spec, s0, lo - 1e-6, n_look, w).min() < band[0]
    if hi < 40.0:
        assert _windows(hist, spec, s0, hi + 1e-6, n_look, w).max() > band[1]


def test_no_command_keeps_the_band_gives_the_middle_of_the_ends():
    """A past far below the band that the servo cannot make up for within the look-ahead: the range
    collapses to one command, the servo's maximum (the nearest it can do)."""
    f_old = np.zeros(50)
    lo, hi = window_bounds(f_old, np.full(50, 10.0), 0.0, 10.0, (0.0, 40.0, 1.0, 2.0), 5, (0.8, 1.25), 0.0, 40.0)
    assert lo == hi == 40.0


def test_force_history_keeps_the_last_samples_newest_first():
    h = ForceHistory(2, 3)
    h.fill([1.0, 2.0], [10.0, 20.0])
    for k in range(4):
        h.push([3.0 + k, 30.0 + k], [11.0 + k, 21.0 + k])
    f, p = h.newest_first(0)
    assert f.tolist() == [6.0, 5.0, 4.0] and p.tolist() == [14.0, 13.0, 12.0]
    assert h.newest_first(1)[0].tolist() == [33.0, 32.0, 31.0]
