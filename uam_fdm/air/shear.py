"""Wind shear: how the steady wind's horizontal speed grows with height above the field.

The scenario gives the steady wind at a reference height z_ref (10 m above the field by default,
the meteorological standard). A :class:`WindShear` scales its horizontal components at height z;
the vertical component is left as given (a mean updraft is not a boundary-layer profile).

Laws (z: height above the field [m], floored at ``floor_m`` so each law stays finite near the ground)
    uniform  u(z) = u_ref                                   (the default: no shear)
    power    u(z) = u_ref (z / z_ref)^alpha                 alpha in [0, 0.6]
    log      u(z) = u_ref ln(z / z0) / ln(z_ref / z0)       roughness length z0 in [0.001, 3] m

Typical city values: Davenport's power-law exponents are about 0.16 over open country, 0.28 over
suburbs and towns and 0.40 over large city centres; the neutral log law's roughness length is
about 0.5-1 m over suburbs and towns and 1-2 m over city centres with tall buildings (ESDU 72026;
Wieringa 1992). Floor: 1 m for the power law, max(1 m, 2 z0) for the log law (below 2 z0 the log
law is meaningless inside the roughness sublayer; it is zero at z0).

Limits: the law is the city's mean boundary-layer profile over height above the field. Street
canyons, roof-edge separation, building wakes and the zero-plane displacement are not modelled,
and the wind's direction does not turn with height (no Ekman spiral).

Bit-identity: :meth:`WindShear.factor` uses NumPy's ufuncs for every path (a scalar or an array):
Python's ``math.log`` and ``**`` differ from NumPy's SIMD ``log``/``power`` in the last bit for a
few inputs, and the runner's scalar wind and the learned pilot's batched wind must agree exactly.
"""
from __future__ import annotations

import enum
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from uam_fdm.files.strict import checked_number

__all__ = ["ShearLaw", "WindShear", "EXPONENT_RANGE", "ROUGHNESS_RANGE_M", "REFERENCE_HEIGHT_RANGE_M",
           "MIN_HEIGHT_M"]

EXPONENT_RANGE = (0.0, 0.6)  # 0: uniform; 0.4-0.5 is already a very rough city centre
ROUGHNESS_RANGE_M = (0.001, 3.0)  # from mown grass to the roughest city centres
REFERENCE_HEIGHT_RANGE_M = (1.0, 300.0)  # anemometer masts to tall roof-top stations
MIN_HEIGHT_M = 1.0  # floor of every law's height


class ShearLaw(str, enum.Enum):
    """Shear law, as named in scenario files (``uniform | power | log``)."""

    UNIFORM = "uniform"
    POWER = "power"
    LOG = "log"


@dataclass(frozen=True)
class WindShear:
    """The steady wind's profile over height above the field.

    Attributes:
        law: uniform, power or log (a string is accepted and parsed).
        reference_height_m: height above the field where the steady wind is given [m].
        exponent: power-law exponent alpha (power law only, else None).
        roughness_m: log-law roughness length z0 [m] (log law only, else None).

    Raises:
        ValueError: naming the parameter and its value if one is out of range, missing or given
            for the wrong law, or if the reference height lies below the law's floor.
    """

    law: ShearLaw = ShearLaw.UNIFORM
    reference_height_m: float = 10.0
    exponent: float | None = None
    roughness_m: float | None = None

    def __post_init__(self) -> None:
        try:
            law = ShearLaw(self.law.strip().lower() if isinstance(self.law, str) else self.law)
        except ValueError:
            raise ValueError(f"law must be one of {', '.join(v.value for v in ShearLaw)}, got {self.law!r}") from None
        object.__setattr__(self, "law", law)
        ref = checked_number("reference_height_m", self.reference_height_m, REFERENCE_HEIGHT_RANGE_M,
                             "m above the field")
        object.__setattr__(self, "reference_height_m", ref)
        needs = {ShearLaw.POWER: "exponent", ShearLaw.LOG: "roughness_m"}.get(law)
        for name, bounds, unit in (("exponent", EXPONENT_RANGE, "dimensionless"),
                                   ("roughness_m", ROUGHNESS_RANGE_M, "m")):
            value = getattr(self, name)
            if name != needs:
                if value is not None:
                    raise ValueError(f"{name}={value!r} does not apply to the {law.value} law")
                continue
            if value is None:
                raise ValueError(f"the {law.value} law needs {name}")
            object.__setattr__(self, name, checked_number(name, value, bounds, unit))
        if ref < self.floor_m:
            raise ValueError(f"reference_height_m={ref} is below the {law.value} law's floor {self.floor_m} m "
                             f"(max(1 m, 2 z0))")

    @property
    def floor_m(self) -> float:
        """Lowest height the law is evaluated at [m]; lower heights get its value there."""
        if self.law is ShearLaw.LOG:
            return max(MIN_HEIGHT_M, 2.0 * float(self.roughness_m))  # type: ignore[arg-type]
        return MIN_HEIGHT_M

    @property
    def uniform(self) -> bool:
        """True if the wind is the same at every height (the uniform law, or a power law with alpha = 0)."""
        return self.law is ShearLaw.UNIFORM or (self.law is ShearLaw.POWER and self.exponent == 0.0)

    def factor(self, z_m: ArrayLike) -> NDArray[np.float64]:
        """u(z) / u_ref at heights z_m above the field (any shape, metres; floored at `floor_m`).

        Returns:
            Same shape as z_m (a NumPy scalar for a scalar); exactly 1 at the reference height
            (power, log) and everywhere for the uniform law.
        """
        z = np.maximum(np.asarray(z_m, dtype=np.float64), self.floor_m)
        if self.law is ShearLaw.POWER:
            assert self.exponent is not None  # __post_init__ requires it for the power law
            return np.power(z / self.reference_height_m, self.exponent)
        if self.law is ShearLaw.LOG:
            z0 = float(self.roughness_m)  # type: ignore[arg-type]
            return np.log(z / z0) / np.log(self.reference_height_m / z0)
        return np.ones_like(z)

    def steady_enu_m_s(self, steady_ref_enu_m_s: ArrayLike, z_m: float) -> NDArray[np.float64]:
        """(3,) steady wind (east, north, up) [m/s] at height z_m [m] from its value at the reference height."""
        k = float(self.factor(z_m))
        w = np.array(steady_ref_enu_m_s, dtype=np.float64).reshape(3)
        return np.array([w[0] * k, w[1] * k, w[2]])

    def describe(self) -> str:
        """Short words for reports, e.g. "power law, alpha 0.3, from 10 m"."""
        if self.law is ShearLaw.POWER:
            return f"power-law shear, alpha {self.exponent:g}, given at {self.reference_height_m:g} m"
        if self.law is ShearLaw.LOG:
            return f"log-law shear, z0 {self.roughness_m:g} m, given at {self.reference_height_m:g} m"
        return "no shear"

    def to_dict(self) -> dict[str, Any]:
        """Plain data (run.json): law, reference_height_m, exponent, roughness_m."""
        return {"law": self.law.value, "reference_height_m": self.reference_height_m,
                "exponent": self.exponent, "roughness_m": self.roughness_m}
