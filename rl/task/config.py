"""The navigation task: what a learned pilot is trained and evaluated on (`NavConfig`), and fixed episodes.

`NavConfig` gathers the vehicle, the rates, the senses' settings (`rl.sensing`), the city and leg
distributions (`rl.task.cities`), the air and the reward (`rl.task.reward`); a policy folder's
config.json stores it (`to_dict` / `from_dict`). The per-vehicle tasks are in `rl.task.vehicles`.
"""
from __future__ import annotations

from dataclasses import asdict, dataclass, field, fields, replace

from rl.sensing.observation import ObservationScales, ObservedContext
from rl.sensing.perception import PerceptionConfig
from rl.sensing.route import RouteConfig
from rl.task.air import AirDistribution
from rl.task.cities import EVAL_SEEDS, TRAIN_SEEDS, CityDistribution, CityMixture, TaskDistribution, cities_from_dict
from rl.task.reward import RewardConfig
from uam_fdm.city.buildings import BuildingMap
from uam_fdm.city.map_error import MAP_ERROR_LEVELS
from uam_fdm.pilot import Task
from uam_fdm.sensing.specs import LEVELS as SENSING_LEVELS
from uam_fdm.sensing.specs import SensingConfig, sensing_preset

_LEGACY_AIR = {"turbulence": "turbulence", "steady_wind_max_m_s": "steady_wind_max_m_s"}
"""Settings of policies trained before `NavConfig.air`: one turbulence level and the wind's top speed."""


@dataclass(frozen=True)
class NavConfig:
    """Everything that defines the navigation task (all defaults are the shipped policy's).

    Attributes:
        vehicle: preset name or vehicle YAML path.
        physics_hz, control_hz: physics and low-level control period rates [Hz].
        decision_hz: the policy's decision rate [Hz] (must divide control_hz); the command is held
            between decisions.
        perception: rays and height map (`rl.sensing.perception`); route: the geodesic potential (`rl.sensing.route`).
        scales: the observation's length scales (`rl.sensing.observation`); the clearance is measured
            exactly up to `scales.clearance_m` and reads that value beyond.
        observe: what the observation holds beyond the base elements and the perception (the air, the
            geofence, a history of decisions; `rl.sensing.observation.ObservedContext`).
        city_split: "train" or "eval": which seed range the city pool comes from.
        city_pool_size: number of cities in the pool; city_pool_offset: first seed within the range.
        cities: city generator parameter ranges (`CityDistribution`), or several with the share of cities from
            each (`CityMixture`); tasks: start/goal distribution.
        air: the air of the episodes (`rl.task.air`): fields (elevation, temperature), turbulence levels,
            steady wind.
        wind_pool_size: turbulence stacks per turbulence level (series at the probe heights up to the
            cities' ceiling, `uam_fdm.air.wind.gust_stack`) shared by all episodes (each episode starts at a
            random sample of one of its level's); wind_series_s: length of each [s]. The steady wind is
            uniform with height.
        reward: reward weights.
        map_error: the map-error levels (`uam_fdm.city.map_error` presets) an episode draws from, uniformly: it
            collides with and senses the level's truth and follows a route field drawn from its prior map
            (`rl.sensing.truth`). ("exact",): every map is its city, as before the setting existed.
        map_error_draws: draws banked per city of each level that is not exact (each from its own seed, derived
            from the city seed and the draw index); an episode draws one uniformly.
        exact_maps_at_perfect: an episode that draws `perfect` sensing flies its city's exact map whatever map-error
            level it drew (the draws are made as without the setting, so every other episode is the same). At
            `perfect` the env hands the pilot the truth's exact senses, while the comparison hands a pilot without
            sensors the prior map's: over a map with error the two differ, and no pilot in the comparison meets the
            env's case. Needs "exact" among `map_error`.
        sensing: the sensing levels (`uam_fdm.sensing.specs` presets) an episode draws from, uniformly: at
            `perfect` the pilot observes the true state and the truth's exact senses; at another level it observes
            its navigation estimate and its lidar (`learned_pilot_sensing`; `rl.env.onboard_slots`).
            ("perfect",): every number as before the setting existed.
    """

    vehicle: str = "small_quad"
    physics_hz: float = 500.0
    control_hz: float = 50.0
    decision_hz: float = 10.0
    perception: PerceptionConfig = field(default_factory=PerceptionConfig)
    route: RouteConfig = field(default_factory=RouteConfig)
    scales: ObservationScales = field(default_factory=ObservationScales)
    observe: ObservedContext = field(default_factory=ObservedContext)
    city_split: str = "train"
    city_pool_size: int = 1024
    city_pool_offset: int = 0
    cities: CityDistribution | CityMixture = field(default_factory=CityDistribution)
    tasks: TaskDistribution = field(default_factory=TaskDistribution)
    air: AirDistribution = field(default_factory=AirDistribution)
    wind_pool_size: int = 16
    wind_series_s: float = 400.0
    reward: RewardConfig = field(default_factory=RewardConfig)
    map_error: tuple[str, ...] = ("exact",)
    map_error_draws: int = 4
    exact_maps_at_perfect: bool = False
    sensing: tuple[str, ...] = ("perfect",)

    def __post_init__(self) -> None:
        object.__setattr__(self, "sensing", tuple(self.sensing))
        bad_sensing = [v for v in self.sensing if v not in SENSING_LEVELS]
        if not self.sensing or bad_sensing or len(set(self.sensing)) != len(self.sensing):
            raise ValueError(f"sensing must be distinct levels from {', '.join(SENSING_LEVELS)}, "
                             f"got {list(self.sensing)}")
        object.__setattr__(self, "map_error", tuple(self.map_error))
        bad = [v for v in self.map_error if v not in MAP_ERROR_LEVELS]
        if not self.map_error or bad or len(set(self.map_error)) != len(self.map_error):
            raise ValueError(f"map_error must be distinct levels from {', '.join(MAP_ERROR_LEVELS)}, "
                             f"got {list(self.map_error)}")
        if self.exact_maps_at_perfect is not False and (self.exact_maps_at_perfect is not True
                                                         or "exact" not in self.map_error):
            raise ValueError(f"exact_maps_at_perfect needs true or false and 'exact' among map_error, got "
                             f"{self.exact_maps_at_perfect!r} with {list(self.map_error)}")
        if isinstance(self.map_error_draws, bool) or not isinstance(self.map_error_draws, int) \
                or not 1 <= self.map_error_draws <= 1000:
            raise ValueError(f"map_error_draws must be an integer in [1, 1000], got {self.map_error_draws!r}")
        if self.city_split not in ("train", "eval"):
            raise ValueError(f"city_split must be 'train' or 'eval', got {self.city_split!r}")
        if self.city_pool_size < 1 or self.wind_pool_size < 1:
            raise ValueError("city_pool_size and wind_pool_size must be positive")
        ratio = self.control_hz / self.decision_hz if self.decision_hz > 0 else 0.0
        if self.decision_hz <= 0 or abs(ratio - round(ratio)) > 1e-9 or round(ratio) < 1:
            raise ValueError(f"decision_hz {self.decision_hz} must divide control_hz {self.control_hz}")

    @property
    def action_repeat(self) -> int:
        """Control periods per decision."""
        return int(round(self.control_hz / self.decision_hz))

    def city_seeds(self) -> list[int]:
        """The pool's city seeds."""
        rng = TRAIN_SEEDS if self.city_split == "train" else EVAL_SEEDS
        seeds = list(rng[self.city_pool_offset: self.city_pool_offset + self.city_pool_size])
        if len(seeds) < self.city_pool_size:
            raise ValueError(f"city pool {self.city_pool_offset}+{self.city_pool_size} exceeds the "
                             f"{self.city_split} range")
        return seeds

    def to_dict(self) -> dict:
        """Plain-data form (for the policy's config file)."""
        return asdict(self)

    @classmethod
    def from_dict(cls, d: dict) -> NavConfig:
        """The inverse of `to_dict`.

        Raises:
            ValueError: a key this version does not know (e.g. a policy written by an older
                version), naming it.
        """
        d = dict(d)
        legacy = {k: d.pop(k) for k in _LEGACY_AIR if k in d}  # written before the task described the air
        if legacy and "air" in d:
            raise ValueError(f"navigation settings {sorted(legacy)} and 'air' both given")
        if legacy:
            d["air"] = {_LEGACY_AIR[k]: ([v] if k == "turbulence" else v) for k, v in legacy.items()}
        if "cities" in d:
            d["cities"] = cities_from_dict(d["cities"])
        nested = {"tasks": TaskDistribution, "reward": RewardConfig,
                  "perception": PerceptionConfig, "route": RouteConfig, "scales": ObservationScales,
                  "air": AirDistribution, "observe": ObservedContext}
        known = {f.name for f in fields(cls)}
        unknown = sorted(set(d) - known)
        if unknown:
            raise ValueError(f"unknown navigation settings {unknown} (written by another version?)")
        for key, typ in nested.items():
            if key in d:
                sub = d[key]
                bad = sorted(set(sub) - {f.name for f in fields(typ)})
                if bad:
                    raise ValueError(f"unknown {key} settings {bad} (written by another version?)")
                d[key] = typ(**{k: tuple(v) if isinstance(v, list) else v for k, v in sub.items()})
        return cls(**d)


LEARNED_LIDAR_CHANNELS = 8
LEARNED_LIDAR_AZIMUTH_STEP_DEG = 10.0


def learned_pilot_sensing(level: str, mass_kg: float) -> SensingConfig:
    """What the learned pilot carries at sensing level `level` on a vehicle of `mass_kg` [kg]: the level's preset
    (`sensing_preset`) with the learned pilot's lidar (`learned_lidar`).

    Raises:
        ValueError: an unknown level.
    """
    return learned_lidar(sensing_preset(level, mass_kg))


_LEARNED_LIDAR_KEYS = ("lidar.channels", "lidar.horizontal_resolution_deg")


def learned_lidar(config: SensingConfig) -> SensingConfig:
    """`config` (a level's preset, or a scenario's with its overrides) with its lidar reduced to what the learned
    pilot carries: `LEARNED_LIDAR_CHANNELS` channels over the part's vertical field of view and a
    `LEARNED_LIDAR_AZIMUTH_STEP_DEG` azimuth step (8 x 36 beams a scan, where the small quad's VLP-16 has 16 x 1800).
    A full scan per slot would cost a training batch far more than its physics (perf/batch_lidar.py measures 8 x 36
    at about 2 % of a full scan's cost). Range, noise, dropout, rate and every other sensor stay `config`'s; at
    `perfect` nothing is simulated and `config` is returned as it is. Applied twice it changes nothing more.
    """
    if config.perfect:
        return config
    lidar = replace(config.lidar, channels=LEARNED_LIDAR_CHANNELS,
                    horizontal_resolution_deg=LEARNED_LIDAR_AZIMUTH_STEP_DEG)
    added = tuple(k for k in _LEARNED_LIDAR_KEYS if k not in config.overridden)
    return replace(config, lidar=lidar, overridden=config.overridden + added)


@dataclass(frozen=True)
class FixedEpisodes:
    """Episodes from a scenario instead of sampled ones: cities and (city index, task) pairs, cycled."""

    cities: tuple[BuildingMap, ...]
    tasks: tuple[tuple[int, Task], ...]

