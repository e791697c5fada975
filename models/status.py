"""One status vocabulary for every result of the workbench (diffrax ``RESULTS`` style).

Results carry ``status`` (a :class:`Status`) and ``message`` (the human-readable detail);
callers test ``result.status is Status.FALLBACK``, never the text.
"""

from __future__ import annotations

import enum

__all__ = ["Status"]


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
        return self in (Status.OK, Status.WARNING, Status.HOLD)

    def __str__(self) -> str:
        return self.value
