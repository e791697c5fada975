"""Compatibility re-export: the finite-difference baseline lives in :mod:`estimators.online.fd`."""

from estimators.online.fd import FiniteDifference  # noqa: F401
from estimators.online.options import FDOptions  # noqa: F401

__all__ = ["FiniteDifference", "FDOptions"]
