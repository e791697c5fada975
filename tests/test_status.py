"""One meaning of success and one aggregate of parts (models/status.py)."""

import dataclasses

import numpy as np
import pytest

from estimators.base import Estimate
from mitigate.controllers.base import Action
from models.status import Status


@pytest.mark.parametrize("status", list(Status))
def test_every_result_success_is_status_success(status):
    # an action, an estimate: the same answer as Status.success, nothing of their own
    assert Action({}, status).success is status.success
    assert Estimate(0.0, np.zeros(1), np.eye(1), ("x",), status).success is status.success
    assert status.success is (status in (Status.OK, Status.WARNING, Status.HOLD))


def test_fallback_is_not_success():
    assert not Status.FALLBACK.success and Status.WARNING.success


def test_worst_of_parts():
    assert Status.worst([]) is Status.OK
    assert Status.worst([Status.OK, Status.HOLD]) is Status.OK
    assert Status.worst([Status.OK, Status.WARNING]) is Status.WARNING
    assert Status.worst([Status.OK, Status.FALLBACK]) is Status.WARNING
    assert Status.worst([Status.WARNING, Status.DIVERGED, Status.OK]) is Status.FAILED
    assert Status.worst(iter([Status.NOT_CONVERGED])) is Status.FAILED

    @dataclasses.dataclass
    class Part:
        status: Status

    assert Status.worst([Part(Status.OK), Part(Status.WARNING)]) is Status.WARNING
