"""planners: the classical pilot (OMPL RRT* path, time-parameterised reference, CasADi MPC tracker)."""
