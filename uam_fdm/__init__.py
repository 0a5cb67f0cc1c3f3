"""uam_fdm: the world both pilots fly in.

Vehicle physics (one CasADi model, compiled), the JSBSim atmosphere and wind, and the city.
Frames: world ENU (x east, y north, z up, metres above the field), body FLU; SI units throughout.
"""
