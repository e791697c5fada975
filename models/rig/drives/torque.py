"""A torque drive: the input is the torque applied to the drive body [N m] (seed 001's rig2, a field
string's rotary table).  The speed follows from the balance of torques; ``[drive] torque_max`` limits
the torque the plant applies (it clips its input)."""

from __future__ import annotations

from models.rig.drives.base import Drive

__all__ = ["TorqueDrive"]


class TorqueDrive(Drive):
    """The input is a torque on the drive body (module docstring)."""

    kind = "torque"
    doc = "a torque applied to the drive body (the input, N m), optionally limited by torque_max"
    setpoint = "torque"
    on_body = True
    keys = frozenset({"torque_max"})

    @classmethod
    def parse_settings(cls, table, ctx) -> dict:
        from models.rig.fields import value_ref
        if "torque_max" not in table:
            return {}
        r = value_ref(table["torque_max"], "torque", "drive.torque_max", ctx)
        if r.kind != "const" or not r.constant > 0:
            raise ctx.err("drive.torque_max", f"must be a torque > 0 (a value, e.g. \"25 kN m\"), got "
                                              f"{table['torque_max']!r}")
        return {"torque_max": r.constant}

    def torque(self, model, x, un, P):
        return un[self.spec.input]

    def torque_limit(self, P=None) -> float:
        """``[drive] torque_max`` [N m] (inf: none)."""
        return float(self.spec.torque_max)

    def power(self, model, params, X, U):
        """The applied torque times the drive body's speed."""
        return U[:, model.inputs.index(self.spec.input)] * X[:, model.speed_index(self.spec.body)]


