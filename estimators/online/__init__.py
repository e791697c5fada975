"""Online state estimators on any rig: EKF, MHE, the finite-difference baseline, and the
observability check they run on themselves.

- :mod:`estimators.online.options`: ``EKFOptions``, ``MHEOptions``, ``FDOptions``
- :mod:`estimators.online.model`: the estimation model both filters share (its docstring
  gives the defaults and why)
- :mod:`estimators.online.observability`: ``observability`` -> ``ObservabilityReport``
- :mod:`estimators.online.ekf`, :mod:`estimators.online.mhe`, :mod:`estimators.online.fd`
- :mod:`estimators.online.factory`: ``make_estimator(spec, context)``
"""
