"""One status vocabulary for every result of the workbench (diffrax ``RESULTS`` style).

Results carry ``status`` (a :class:`Status`) and ``message`` (the human-readable detail);
callers test ``result.status is Status.FALLBACK`` or ``result.success``, never the text.

One meaning of success, for every result (a fit, a linearisation, a run, an action, an estimate):
:attr:`Status.success` -- OK, WARNING (succeeded, the message says what to look at) or HOLD (a
multi-rate controller kept its plan).  Every ``success`` property of a result is
``self.status.success`` and nothing else.  FALLBACK is *not* success: the controller or
estimator did not produce its own answer, the documented fallback did (the closed loop counts
those calls and the run carries WARNING).  A whole made of parts (the runs of a scenario, the
cells of a benchmark, the points of a sweep) takes :meth:`Status.worst` of its parts.
"""

from __future__ import annotations

import enum

__all__ = ["Status", "Outcome"]


class Status(enum.Enum):
    """What became of a computation."""

    OK = "ok"
    #: succeeded, with warnings in the result's ``warnings`` / ``message``
    WARNING = "ok, with warnings"
    #: a controller or estimator answered with its documented fallback
    FALLBACK = "fallback"
    #: a multi-rate controller held its previous action (no new plan this call)
    HOLD = "hold"
    #: an optimiser stopped without meeting its tolerance (iteration limit, line search)
    NOT_CONVERGED = "not converged"
    #: the plant left its physical bounds (non-finite or runaway states)
    DIVERGED = "diverged"
    #: the computation failed
    FAILED = "failed"

    @property
    def success(self) -> bool:
        """OK, WARNING or HOLD: the only definition of success (see the module docstring)."""
        return self in (Status.OK, Status.WARNING, Status.HOLD)

    @classmethod
    def worst(cls, parts) -> "Status":
        """The status of a whole made of parts (runs, benchmark cells, sweep points).

        Parameters
        ----------
        parts : iterable of Status (or of objects with a ``status`` attribute)

        Returns
        -------
        Status.FAILED if any part did not succeed (NOT_CONVERGED, DIVERGED, FAILED), else
        Status.WARNING if any part carries warnings or answered with its documented fallback
        (WARNING, FALLBACK: the whole still has its answer, as the closed loop's run does), else
        Status.OK (also for no parts).
        """
        seen = [p if isinstance(p, Status) else p.status for p in parts]
        if any(not p.success and p is not cls.FALLBACK for p in seen):
            return cls.FAILED
        if any(p in (cls.WARNING, cls.FALLBACK) for p in seen):
            return cls.WARNING
        return cls.OK

    def __str__(self) -> str:
        return self.value


class Outcome:
    """Base of every result that carries a ``status``: its ``success`` is ``status.success``
    (the one definition), never a test of its own."""

    __slots__ = ()

    @property
    def success(self) -> bool:
        """Whether the computation succeeded: ``self.status.success`` (OK, WARNING or HOLD)."""
        return self.status.success
