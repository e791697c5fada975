"""Compatibility re-export: the MHE lives in :mod:`estimators.online.mhe`."""

from estimators.online.mhe import MHE  # noqa: F401
from estimators.online.options import MHEOptions  # noqa: F401

__all__ = ["MHE", "MHEOptions"]
