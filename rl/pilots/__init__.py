"""The learned pilots as `uam_fdm.pilot.Pilot`s: the trained policy and the potential field."""
