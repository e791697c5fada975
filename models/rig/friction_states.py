"""The states of a rig's friction laws (LuGre's bristles, rate-and-state's contact age): where they sit
in the state vector, their derivatives, their values at steady sliding and their sizes.
:class:`FrictionStates` is a mixin of :class:`models.rig.RigModel` (the laws: :mod:`models.friction`,
:mod:`models.friction_state`)."""

from __future__ import annotations

import numpy as np

__all__ = ["FrictionStates"]


class FrictionStates:
    """The friction laws' own states of a rig (see the module docstring); the model sets ``_fstate``
    (contact name -> state indices), ``_laws`` and ``_contact_groups``."""

    @property
    def friction_states(self) -> tuple[int, ...]:
        """Indices of the friction laws' own states in the state vector (empty for memoryless laws)."""
        return tuple(j for idx in self._fstate.values() for j in idx)

    def friction_state_index(self, contact: str) -> tuple[int, ...]:
        """Indices of contact ``contact``'s law states in the state vector (empty if memoryless)."""
        self.contact(contact)
        return self._fstate.get(contact, ())

    def friction_state_guess(self, speed: float, u, P) -> dict:
        """``{state index: value}``: each law-with-state's states at steady sliding at ``speed`` [rad/s]
        (its ``steady`` function; 0 where a law gives none), numeric."""
        un = self._named_inputs(u)
        out = {}
        for c in self.spec.contacts:
            law = self._laws[c.name]
            if c.name not in self._fstate:
                continue
            N, r, LP = self.contact_args(c, P, un)
            vals = law.steady(speed, N * r, **LP) if law.steady is not None else [0.0] * len(law.states)
            for j, v in zip(self._fstate[c.name], vals):
                v = float(v)
                out[j] = v if np.isfinite(v) else 0.0
        return out

    def rest_free(self, i: int) -> bool:
        """True when contact body ``i``'s friction vanishes at zero speed whatever its laws' states (a
        memoryless regularised law, rate-and-state's arcsinh form; not LuGre's bristles)."""
        return all(not self._laws[c.name].stateful or self._laws[c.name].rest_free for c in self._contact_groups[i])

    def friction_state_rates(self, x, u, P) -> list:
        """Derivatives of the friction laws' states (in ``friction_states`` order) at the state ``x``."""
        un = self._named_inputs(u)
        out = []
        for i, g in enumerate(self._contact_groups):
            v = x[self.contacts[i]]
            for c in g:
                if c.name in self._fstate:
                    N, r, LP = self.contact_args(c, P, un)
                    out.extend(self._laws[c.name].dynamic_torque(v, [x[j] for j in self._fstate[c.name]], N, r, LP)[1])
        return out

    def friction_state_scale(self, params) -> dict:
        """``{state name: size}``: each law-with-state's states at steady sliding at the rig's operating
        point (LuGre's deflection g(w)/sigma0; at least 1 for a dimensionless state such as
        rate-and-state's log age), e.g. an estimator's prior standard deviation (the state at power-on
        is not known)."""
        if not self._fstate:
            return {}
        from models.rig.steady import nominal_operating_point
        try:
            xs = np.asarray(self.sliding_guess(nominal_operating_point(self, params)[0], params), float)
        except Exception:  # noqa: BLE001 - a rest state of zeros then
            xs = np.zeros(self.nx)
        out = {}
        for j in self.friction_states:
            v = abs(float(xs[j])) if np.isfinite(xs[j]) else 0.0
            out[self.states[j]] = max(v, 1.0) if self.state_units[j] == "-" else (v if v > 0 else 1e-3)
        return out
