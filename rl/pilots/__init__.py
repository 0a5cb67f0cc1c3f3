"""The learned pilots as `uam_fdm.pilot.Agent`s: the trained policy and the potential field."""
