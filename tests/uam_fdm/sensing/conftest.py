"""Fixtures shared by the sensing tests."""
from __future__ import annotations

import pytest

from uam_fdm.air.atmosphere import Atmosphere, AtmosphereConditions


@pytest.fixture(scope="module")
def air() -> list[Atmosphere]:
    """Two fields: a hot day and a high field (the barometer's pressure column differs per slot)."""
    return [Atmosphere.from_jsbsim(AtmosphereConditions(isa_offset_k=15.0), z_max_m=200.0),
            Atmosphere.from_jsbsim(AtmosphereConditions(elevation_m=1500.0), z_max_m=200.0)]
