"""A simulated run as the DAQ logs it when it powers on mid-run: one helper for the estimator tests.

``powered_on(sim, k0)`` keeps the samples from ``k0`` on, with the incremental encoders reading 0
at power-on (the shaft is twisted then, so the estimators must find the power-on twists).
"""

#: rig3's incremental encoders
ENCODERS = ("theta1", "theta2", "theta3")


def powered_on(sim, k0: int, encoders=ENCODERS):
    """``(t, x, y)`` of a :class:`models.plant.SimResult` from sample ``k0``, the ``encoders``
    channels zeroed there."""
    y = {c: v[k0:].copy() for c, v in sim.y.items()}
    for c in encoders:
        y[c] -= y[c][0]
    return sim.t[k0:], sim.x[k0:], y
