"""Estimators: parameter estimation from logs, and online state estimation (EKF, MHE)."""
