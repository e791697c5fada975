"""Compatibility re-export: the EKF lives in :mod:`estimators.online.ekf`."""

from estimators.online.ekf import EKF, ekf_step_function  # noqa: F401
from estimators.online.options import EKFOptions  # noqa: F401

__all__ = ["EKF", "EKFOptions", "ekf_step_function"]
