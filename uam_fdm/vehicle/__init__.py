"""The vehicle: parameters and presets, the one CasADi model, the low-level controller, and the
compiled dynamics (code generation and the batched C driver behind `VehicleDynamics`).

Body frame FLU, origin at the centre of mass; SI units."""
from uam_fdm.vehicle.dynamics import PeriodResult, VehicleDynamics
from uam_fdm.vehicle.model import StateLayout, hover_state, make_env
from uam_fdm.vehicle.params import ControllerConfig, VehicleParams, load_vehicle, preset_names

__all__ = ["ControllerConfig", "PeriodResult", "StateLayout", "VehicleDynamics", "VehicleParams", "hover_state",
           "load_vehicle", "make_env", "preset_names"]
