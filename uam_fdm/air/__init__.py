"""The air: JSBSim's standard atmosphere above the field, the steady wind with its shear, and
MIL-F-8785C turbulence. World frame ENU; heights in metres above the field."""
from uam_fdm.air.atmosphere import Atmosphere, AtmosphereConditions
from uam_fdm.air.shear import ShearLaw, WindShear
from uam_fdm.air.wind import TurbulenceLevel, WindBank, WindConditions, WindField

__all__ = ["Atmosphere", "AtmosphereConditions", "ShearLaw", "TurbulenceLevel", "WindBank", "WindConditions",
           "WindField", "WindShear"]
