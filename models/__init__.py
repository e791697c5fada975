"""Rig models: rig files and their builder, parameter sets, friction laws, the plant simulator."""

from models.errors import ConfigError, DataError, SolverFailure
from models.params import ParameterSet, load_params, published
from models.rig import RigModel, get_model, load_rig, shipped_rigs

__all__ = [
    "ConfigError",
    "DataError",
    "SolverFailure",
    "ParameterSet",
    "load_params",
    "published",
    "RigModel",
    "get_model",
    "load_rig",
    "shipped_rigs",
]
