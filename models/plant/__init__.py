"""The plant: the exact stick/slip step (:mod:`models.plant.hybrid`) and the simulator with
its sensors and actuators (:mod:`models.plant.simulator`)."""

from models.plant.hybrid import hybrid_step_function
from models.plant.simulator import (MAX_SAMPLES, Plant, SimOptions, SimResult, Trajectory, plant_integration, simulate,
                                    step_function)

__all__ = ["hybrid_step_function", "Plant", "SimOptions", "SimResult", "Trajectory", "simulate", "step_function", "plant_integration", "MAX_SAMPLES"]
