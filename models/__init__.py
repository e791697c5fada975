"""Rig models: parameter sets, friction laws, CasADi models, discretisation and the plant simulator."""

from models.errors import ConfigError, DataError, SolverFailure
from models.params import (
    ParameterSet,
    Rig3Params,
    Rig2Params,
    LeadScrewParams,
    DiscParams,
    load_params,
    published,
    PARAM_CLASSES,
)
from models.rigs import get_model, MODEL_NAMES

__all__ = [
    "ConfigError",
    "DataError",
    "SolverFailure",
    "ParameterSet",
    "Rig3Params",
    "Rig2Params",
    "LeadScrewParams",
    "DiscParams",
    "load_params",
    "published",
    "PARAM_CLASSES",
    "get_model",
    "MODEL_NAMES",
]
