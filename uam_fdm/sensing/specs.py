"""The sensors a vehicle carries, as data: one frozen spec per sensor, the named real parts they come from, and
the sensing levels (`perfect`, `nominal`, `degraded`) built from them.

Every figure of a named part is its datasheet's (or, where a datasheet gives none, the cited reference's):
docs/sensing.md lists each one with its source. Units are in the field names; noise densities are one-sided
white-noise densities (σ of a sample at rate f is density·√f); random walks are the densities of the bias's
white derivative; "σ" is one standard deviation.
"""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass

LEVELS = ("perfect", "nominal", "degraded")  # the presets of the scenario key `sensing:`
UAM_MASS_KG = 100.0  # a vehicle this heavy or heavier carries the UAM-grade parts (a passenger-class vehicle)


@dataclass(frozen=True)
class ImuSpec:
    """A strapdown IMU (accelerometer and gyro, body FLU axes).

    Attributes:
        part: the part it models.
        rate_hz: sample rate [Hz].
        accel_noise_density_m_s2_rthz: accelerometer white noise [m/s²/√Hz].
        gyro_noise_density_rad_s_rthz: gyro white noise [rad/s/√Hz].
        accel_bias_walk_m_s3_rthz: accelerometer bias random walk [m/s³/√Hz].
        gyro_bias_walk_rad_s2_rthz: gyro bias random walk [rad/s²/√Hz].
        accel_bias_initial_m_s2: σ of the accelerometer bias at power-on (after calibration) [m/s²].
        gyro_bias_initial_rad_s: σ of the gyro bias at power-on (after calibration) [rad/s].
    """

    part: str
    rate_hz: float
    accel_noise_density_m_s2_rthz: float
    gyro_noise_density_rad_s_rthz: float
    accel_bias_walk_m_s3_rthz: float
    gyro_bias_walk_rad_s2_rthz: float
    accel_bias_initial_m_s2: float
    gyro_bias_initial_rad_s: float


@dataclass(frozen=True)
class BaroSpec:
    """A static-pressure barometer read as pressure altitude (the standard atmosphere's inverse).

    Attributes:
        part: the part it models.
        rate_hz: sample rate [Hz].
        noise_m: σ of the white noise of one reading, as altitude [m].
        drift_m_rthz: random walk of its offset (temperature drift) [m/√s].
    """

    part: str
    rate_hz: float
    noise_m: float
    drift_m_rthz: float


@dataclass(frozen=True)
class GnssSpec:
    """A GNSS receiver: a sky of satellites, time-correlated pseudorange errors, blocking and reflections by the
    true buildings, a position fix from the satellites it tracks.

    Attributes:
        part: the receiver it models.
        rate_hz: navigation (fix) rate [Hz].
        pseudorange_sigma_m: σ of each tracked satellite's pseudorange error (user range error), a first-order
            Gauss-Markov process (time-correlated, not white) [m].
        correlation_time_s: that process's correlation time [s].
        velocity_sigma_m_s: σ of each velocity component of a fix (Doppler) [m/s].
        satellites: satellites above the elevation mask in an open sky.
        elevation_mask_deg: lowest elevation used [deg].
        urban_canyon: True: the true buildings block lines of sight (fewer satellites, worse DOP, no fix under
            `min_satellites`); False: an open sky.
        nlos_probability: probability that a blocked satellite is still tracked through a reflection off a wall
            (non-line-of-sight multipath), its pseudorange then longer by the extra path.
        outage_rate_per_min: rate of receiver outages (loss of lock) [1/min]; 0: none.
        max_outage_s: outages last up to this long (uniform) [s].
        min_satellites: fewest tracked satellites for a 3D fix.
    """

    part: str
    rate_hz: float
    pseudorange_sigma_m: float
    correlation_time_s: float
    velocity_sigma_m_s: float
    satellites: int
    elevation_mask_deg: float
    urban_canyon: bool
    nlos_probability: float
    outage_rate_per_min: float
    max_outage_s: float
    min_satellites: int = 4


@dataclass(frozen=True)
class HeadingSpec:
    """A heading aid (a magnetometer read as yaw after calibration).

    Attributes:
        part: the part it models.
        rate_hz: sample rate [Hz].
        noise_rad: σ of the white noise of one heading [rad].
        disturbance_rad: σ of a slowly varying error (steel and currents near buildings), Gauss-Markov [rad].
        correlation_time_s: that error's correlation time [s].
    """

    part: str
    rate_hz: float
    noise_rad: float
    disturbance_rad: float
    correlation_time_s: float


@dataclass(frozen=True)
class LidarSpec:
    """A spinning multi-channel 3D lidar (360° horizontal), mounted at the vehicle's centre, body FLU axes.

    Attributes:
        part: the part it models.
        channels: laser channels (rows), spread evenly over `vertical_fov_deg`.
        vertical_fov_deg: (lowest, highest) elevation of a beam [deg].
        horizontal_resolution_deg: azimuth step [deg] (360 / step columns).
        rate_hz: scans per second [Hz].
        max_range_m: longest range returned [m].
        min_range_m: shortest range returned [m].
        range_noise_m: σ of the range noise at short range [m].
        range_noise_per_m: growth of that σ with range [m per m of range].
        dropout: probability that a beam which hits returns nothing (dark, glass or grazing surfaces).
    """

    part: str
    channels: int
    vertical_fov_deg: tuple[float, float]
    horizontal_resolution_deg: float
    rate_hz: float
    max_range_m: float
    min_range_m: float
    range_noise_m: float
    range_noise_per_m: float
    dropout: float

    @property
    def columns(self) -> int:
        """Azimuth steps per scan."""
        return int(round(360.0 / self.horizontal_resolution_deg))

    @property
    def rays_per_scan(self) -> int:
        return self.channels * self.columns


@dataclass(frozen=True)
class SensingConfig:
    """What a vehicle senses at one level, and how late its stack acts on it.

    Attributes:
        level: the preset it starts from ("perfect", "nominal", "degraded"); a scenario's overrides keep it.
        imu, baro, gnss, heading, lidar: the sensors.
        latency_s: sensing-to-decision latency [s]: a decision acts on the estimate and the scans of this long ago.
        overridden: the dotted keys a scenario changed from the preset (empty: the preset as it is).
    """

    level: str
    imu: ImuSpec
    baro: BaroSpec
    gnss: GnssSpec
    heading: HeadingSpec
    lidar: LidarSpec
    latency_s: float
    overridden: tuple[str, ...] = ()

    @property
    def perfect(self) -> bool:
        """True: the truth is handed through (exact state, exact rays): nothing is simulated."""
        return self.level == "perfect"

    @property
    def label(self) -> str:
        """The level as a report names it ("degraded", or "degraded+" when overridden)."""
        return self.level + ("+" if self.overridden else "")


# ---- named parts (figures and sources: docs/sensing.md) ------------------------------------------------------
_DEG = 0.017453292519943295
_G = 9.80665

BMI088 = ImuSpec(  # Bosch Sensortec BMI088 (Pixhawk 6-class flight controllers)
    part="Bosch BMI088", rate_hz=250.0,
    accel_noise_density_m_s2_rthz=175e-6 * _G, gyro_noise_density_rad_s_rthz=0.014 * _DEG,
    accel_bias_walk_m_s3_rthz=3e-3, gyro_bias_walk_rad_s2_rthz=1e-3 * _DEG * 10,
    accel_bias_initial_m_s2=0.2, gyro_bias_initial_rad_s=0.5 * _DEG)
HG4930 = ImuSpec(  # Honeywell HG4930 tactical-grade MEMS IMU
    part="Honeywell HG4930", rate_hz=200.0,
    accel_noise_density_m_s2_rthz=0.03 / 60.0, gyro_noise_density_rad_s_rthz=0.04 * _DEG / 60.0,
    accel_bias_walk_m_s3_rthz=1e-4, gyro_bias_walk_rad_s2_rthz=1e-6,
    accel_bias_initial_m_s2=0.025e-3 * _G * 10, gyro_bias_initial_rad_s=7.0 * _DEG / 3600.0)
MS5611 = BaroSpec(part="TE MS5611-01BA03", rate_hz=50.0, noise_m=0.10, drift_m_rthz=0.01)
BMP388 = BaroSpec(part="Bosch BMP388", rate_hz=50.0, noise_m=0.07, drift_m_rthz=0.01)
# The datasheets give the horizontal accuracy as CEP (50 %, 24 h static, open sky); σ_ρ is set so that the model's
# open sky (its satellites, 10° mask) has that CEP: CEP = 0.469 σ_ρ at 24 satellites, 0.413 σ_ρ at 30 (simulated
# over 4,000 skies).
NEO_M9N = GnssSpec(  # u-blox NEO-M9N, standalone (no corrections): 2.0 m CEP
    part="u-blox NEO-M9N", rate_hz=10.0, pseudorange_sigma_m=4.3, correlation_time_s=60.0,
    velocity_sigma_m_s=0.05, satellites=24, elevation_mask_deg=10.0, urban_canyon=False,
    nlos_probability=0.0, outage_rate_per_min=0.0, max_outage_s=0.0)
ZED_F9P = dataclasses.replace(NEO_M9N, part="u-blox ZED-F9P (standalone)", pseudorange_sigma_m=3.6,  # PVT: 1.5 m CEP
                              satellites=30)
IST8310 = HeadingSpec(part="iSentek IST8310", rate_hz=50.0, noise_rad=0.5 * _DEG, disturbance_rad=1.0 * _DEG,
                      correlation_time_s=30.0)
RM3100 = HeadingSpec(part="PNI RM3100", rate_hz=50.0, noise_rad=0.2 * _DEG, disturbance_rad=1.0 * _DEG,
                     correlation_time_s=30.0)
VLP16 = LidarSpec(  # Velodyne VLP-16 "Puck" at 600 rpm
    part="Velodyne VLP-16", channels=16, vertical_fov_deg=(-15.0, 15.0), horizontal_resolution_deg=0.2,
    rate_hz=10.0, max_range_m=100.0, min_range_m=0.5, range_noise_m=0.015, range_noise_per_m=1.5e-4, dropout=0.02)
VLP32C = LidarSpec(  # Velodyne VLP-32C "Ultra Puck" at 600 rpm (channels spread evenly here; the part's are denser
    # near the horizon)
    part="Velodyne VLP-32C", channels=32, vertical_fov_deg=(-25.0, 15.0), horizontal_resolution_deg=0.2,
    rate_hz=10.0, max_range_m=200.0, min_range_m=1.0, range_noise_m=0.015, range_noise_per_m=1.5e-4, dropout=0.02)


def _parts(mass_kg: float) -> tuple[ImuSpec, BaroSpec, GnssSpec, HeadingSpec, LidarSpec]:
    """The parts a vehicle of this mass carries: consumer MEMS on a small quad, tactical grade on a UAM."""
    if mass_kg >= UAM_MASS_KG:
        return HG4930, BMP388, ZED_F9P, RM3100, VLP32C
    return BMI088, MS5611, NEO_M9N, IST8310, VLP16


def sensing_preset(level: str, mass_kg: float) -> SensingConfig:
    """The sensing level `level` ("perfect", "nominal" or "degraded") of a vehicle of `mass_kg` [kg].

    `nominal` is the parts' datasheet noise with an open sky; `degraded` is an urban canyon (the true buildings
    block satellites, reflections bias the ones tracked through them, outages up to 30 s), 15 % lidar dropout
    and 100 ms latency. `perfect` names the nominal parts but simulates none of them.

    Raises:
        ValueError: an unknown level.
    """
    if level not in LEVELS:
        raise ValueError(f"unknown sensing level {level!r}; expected one of {', '.join(LEVELS)}")
    imu, baro, gnss, heading, lidar = _parts(mass_kg)
    if level == "degraded":
        gnss = dataclasses.replace(gnss, urban_canyon=True, nlos_probability=0.5, outage_rate_per_min=0.5,
                                   max_outage_s=30.0)
        lidar = dataclasses.replace(lidar, dropout=0.15)
        return SensingConfig("degraded", imu, baro, gnss, heading, lidar, latency_s=0.1)
    return SensingConfig(level, imu, baro, gnss, heading, lidar, latency_s=0.0 if level == "perfect" else 0.02)
