"""D-OSKIL: normal-force modulation from the speed difference along the string.

Canudas de Wit, Rubio and Corchero (IEEE TCST 16(6), 2008) use the weight on bit as a second
control input: the bit-rock torque is proportional to it, so raising it while the bit runs
ahead of the top and lowering it while the bit lags turns the falling (velocity-weakening)
friction that drives stick-slip into an effective damper on the torsional mode.  The law
here::

    N = clip(N_prog + k_n (w_b - w_top), n_min, n_max)

``w_b`` is the speed of the body whose contact the servo presses (rig3: the R2 pin; a
drill-string rig file: the bit, through its weight on bit), ``w_top`` the drive's speed,
``N_prog`` the programmed force (rig3: 0 N, so the pin only ever brakes; a drill string: the
nominal weight on bit, modulated around it).  Speeds are the measured channels, low-passed; a
body the rig does not measure (a field string's bit) has its speed from the scenario's
model-based estimator (an EKF or MHE: :meth:`~mitigate.controllers.base.ControlContext.speed_source`).

Default gain from the rig: the force's friction ``r mu_k k_n`` acts on the relative speed like a
damper; matched to the string's impedance it is ``k_n = Z / (r mu_k)`` (:mod:`mitigate.controllers.tuning`;
rig3: 0.110 / (0.040 x 0.306) = 9.0 N s/rad).  The default doubles it (``gain_factor = 2``): the gain
sweep on the main scenario (``benchmarks/industry_tuning.py``) gave a severity of 0.570 at 9, 0.457 at
20 and 0.408 at 40, with the pin work 1.1, 1.5 and 3.2 J: twice the matched gain is the compromise.  ``mu_k`` is the contact law's kinetic level
(``mu_k``, ``mu_cb`` or ``mu1``), ``r`` its radius.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Mapping

from mitigate.controllers.base import Action, ControlContext, estimated, reading
from mitigate.controllers.compiled import CompiledStepLaw, LawOptions, compiled_action, law_config
from mitigate.controllers.tuning import drive_speed_channel, first_order, np_clip, tuning_for
from mitigate.tunables import Tunable
from models.checks import option
from models.errors import ConfigError

__all__ = ["DOSKILOptions", "DOSKIL"]


@dataclass(frozen=True, kw_only=True)
class DOSKILOptions(LawOptions):
    """D-OSKIL options (scenario keys of ``kind = "doskil"``); 0 means "derive from the rig".

    Parameters
    ----------
    input : the servo input it modulates (default: the rig's first servo)
    gain : ``k_n`` [N s/rad] (0: ``gain_factor Z / (r mu_k)``)
    gain_factor : multiplies the derived gain [-] (2: the sweep's compromise between severity and pin wear)
    n_min, n_max : force range [N] (n_max 0: the servo's range)
    tau : low-pass of the measured speeds [s] (0: 1/80 of the rig's stick-slip period; rig3 29 ms)
    implementation : "c" (compiled) or "python" (:class:`~mitigate.controllers.compiled.LawOptions`)
    """

    input: str = option("", what="a servo input name")
    gain: float = option(0.0, lo=0.0, unit="N s/rad")
    gain_factor: float = option(2.0, lo=0.0, lo_open=True)
    n_min: float = option(0.0, lo=0.0, unit="N")
    n_max: float = option(0.0, lo=0.0, unit="N")
    tau: float = option(0.0, lo=0.0, unit="s")


class DOSKIL(CompiledStepLaw):
    """D-OSKIL normal-force modulation (module docstring)."""

    kind = "doskil"
    options_class = DOSKILOptions
    needs = ("servo", "servo_body_speed", "drive_speed")
    tunables = {"gain_factor": Tunable(low=0.25, high=16.0, doc="the gain in multiples of the matched Z / (r mu_k)")}
    derived = ("gain", "tau", "n_min", "n_max")
    derived_units = {"gain": "N s/rad", "tau": "s", "n_min": "N", "n_max": "N"}

    def __init__(self, options: DOSKILOptions, context: ControlContext):
        super().__init__(options, context)
        m, P = context.model, context.params.as_dict()
        if not m.servo_inputs:
            raise ConfigError(f"{context.where}: D-OSKIL needs a servo on a contact's normal force; rig {m.name!r} "
                              f"has no actuator")
        self.input = options.input or m.servo_inputs[0]
        if self.input not in m.servo_inputs:
            raise ConfigError(f"{context.where}.input must be a servo input ({', '.join(m.servo_inputs)}), "
                              f"got {self.input!r}")
        c = m.contact_of_input(self.input)
        src = context.speed_source(c.body)
        if src is None:
            raise ConfigError(f"{context.where}: needs the speed of {c.body!r}, which rig {m.name!r} does not measure "
                              f"and the estimator does not estimate")
        #: the body's speed channel, or None: its speed is the estimate's ``body_estimate``
        self.body_ch = src[1] if src[0] == "channel" else None
        self.body_estimate = src[1] if src[0] == "estimate" else None
        self.top_ch = drive_speed_channel(context)
        kinetic = m.law(c.name).with_role("kinetic")
        level = dict(c.params).get(kinetic) if kinetic else None
        if options.gain > 0:
            self.gain = options.gain
        else:
            if level is None or c.radius is None:
                raise ConfigError(f"{context.where}.gain: cannot derive it for contact {c.name!r} (law {c.law!r}); "
                                  f"give gain [N s/rad]")
            self.gain = options.gain_factor * tuning_for(m, context.params).Z / (c.radius.value(P) * level.value(P))
        self.tau = options.tau or tuning_for(m, context.params).period / 80.0
        a = m.actuator(self.input)
        self.n_min = max(options.n_min, a.n_min)
        self.n_max = options.n_max or a.n_max
        self.compile_step()

    def c_config(self):
        """The law's C configuration, the channels it reads, the estimates it reads (its body's speed
        when the rig does not measure it)."""
        if self.body_ch is None:
            return (law_config("doskil", n_ch=1, ch_drive=0, est_body=1, period=self.context.period, gain=self.gain,
                               tau=self.tau, n_min=self.n_min, n_max=self.n_max), (self.top_ch,), (self.body_estimate,))
        return law_config("doskil", n_ch=2, ch_body=0, ch_drive=1, period=self.context.period, gain=self.gain,
                          tau=self.tau, n_min=self.n_min, n_max=self.n_max), (self.body_ch, self.top_ch), ()

    def actuated_inputs(self) -> tuple[str, ...]:
        return (self.input,)

    def reset_reference(self) -> None:
        self._d = None

    def _step_impl(self, t: float, measurement: Mapping[str, float], estimate) -> Action:
        if self.compiled is not None:
            return compiled_action(self, t, measurement, estimate, self.input, 0.0, self.context.scheduled(t, self.input))
        wb = (reading(measurement, self.body_ch) if self.body_ch is not None
              else estimated(estimate, self.body_estimate))
        d = wb - reading(measurement, self.top_ch)
        self._d = d if self._d is None else first_order(self._d, d, self.context.period, self.tau)
        n = self.context.scheduled(t, self.input) + self.gain * self._d
        return Action({self.input: np_clip(n, self.n_min, self.n_max)})
