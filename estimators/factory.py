"""Compatibility re-export: the factory lives in :mod:`estimators.online.factory`."""

from estimators.online.factory import ESTIMATOR_KINDS, make_estimator  # noqa: F401

__all__ = ["make_estimator", "ESTIMATOR_KINDS"]
