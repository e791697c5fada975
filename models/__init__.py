"""Rig models: rig files and their builder, parameter sets, friction laws, sensors, the plant, modes.

The Python API::

    from models import get_model, simulate, modes
    rig = get_model("rig3")                       # or a rig file: get_model("my_rig.toml")
    p = rig.published()                           # ParameterSet with units, bounds, provenance
    r = simulate("rig3", p, [3.14, 20.0, 0.0], duration=30.0)
    modes("rig3", p, "clamped").freq_hz
"""

from models import portable as _portable

_portable.pin()        # one OpenBLAS kernel on every machine, before numpy loads it (models/portable.py)

from models.errors import ConfigError, DataError, PluginError, SolverFailure  # noqa: E402
from models.friction import FrictionLaw, LAWS, LawState, Param, get_law, register
from models import friction_state as _friction_state  # noqa: F401 - the laws with state register themselves
from models.logs import Log, read_csv
from models.modal import LinearModel, ModalResult, linearise, modes
from models.stability import sliding_stability, stability_map
from models.params import ParameterSet
from models.plant import Plant, SimOptions, SimResult, simulate
from models.rig import RigModel, get_model, load_params, load_rig, published, shipped_rigs
from models.sensors import SensorOptions
from models.status import Status

__all__ = [
    "ConfigError", "DataError", "PluginError", "SolverFailure", "Status",
    "RigModel", "get_model", "load_rig", "shipped_rigs",
    "ParameterSet", "load_params", "published",
    "FrictionLaw", "LAWS", "LawState", "Param", "get_law", "register",
    "Log", "read_csv",
    "LinearModel", "ModalResult", "linearise", "modes", "sliding_stability", "stability_map",
    "Plant", "SimOptions", "SimResult", "simulate", "SensorOptions",
]
