"""The scenario TOML that many tests write: one builder instead of a copy per test file.

``scenario_toml("[scenario]\\nname = \\"tiny\\"\\nduration = 2.0", controllers=[PI, ("R2 brake", "brake")])``
gives a scenario on rig3 at 30 rpm and N1 = 20 N, the controllers switched on at ``start`` with
the finite-difference estimator, unless told otherwise.
"""

#: the programme most tests run: 30 rpm at N1 = 20 N (rig3's stick-slip operating point)
INPUTS = 'omega_ref = "30 rpm"\nn1 = 20.0'
#: the baseline every comparison includes
PI = ("PI only", "pi")


def scenario_toml(head: str, *, inputs: str = INPUTS, control: str = "start = 1.0", estimator: str = "fd",
                  controllers=(PI,)) -> str:
    """Scenario text: ``head`` (the ``[scenario]`` table and any other tables), ``[inputs]``,
    ``[control]``, ``[estimator] kind`` and one ``[[controllers]]`` table per ``(name, kind[, extra
    lines])``."""
    parts = [head.strip(), "", "[inputs]", inputs.strip(), "", "[control]", control.strip(), "",
             "[estimator]", f'kind = "{estimator}"']
    for c in controllers:
        name, kind, *extra = c
        parts += ["", "[[controllers]]", f'name = "{name}"', f'kind = "{kind}"', *[e.strip() for e in extra]]
    return "\n" + "\n".join(parts) + "\n"
