"""The classical pilot's map of what it senses: unmapped obstacles found, prior parts seen through taken out."""
from __future__ import annotations

from dataclasses import replace

import numpy as np
import octomap
import pytest

from planners.sensed_map import MappingConfig, SensedMap, column_boxes, grown_parts, pack_keys, unpack_keys
from uam_fdm.city.buildings import Building, BuildingMap
from uam_fdm.sensing.lidar import Lidar
from uam_fdm.sensing.raycast import RayCaster
from uam_fdm.sensing.specs import VLP16

LO, HI = (0.0, 0.0, 0.0), (200.0, 200.0, 80.0)
KNOWN = Building(1, (150.0, 100.0), (20.0, 20.0), 40.0)  # in the prior and in the world
UNMAPPED = Building(2, (100.0, 130.0), (10.0, 10.0), 30.0)  # in the world only
PHANTOM = Building(3, (100.0, 70.0), (10.0, 10.0), 30.0)  # in the prior only


def _state(p: np.ndarray) -> np.ndarray:
    x = np.zeros(17)
    x[0:3], x[6] = p, 1.0
    return x


def _mapped(scans: int = 3) -> tuple[SensedMap, np.ndarray]:
    world = BuildingMap([KNOWN, UNMAPPED], LO, HI)
    prior = BuildingMap([KNOWN, PHANTOM], LO, HI)
    lidar = Lidar(VLP16, RayCaster(world), np.random.default_rng(0))
    sensed = SensedMap(prior, MappingConfig(), VLP16.max_range_m)
    p = np.array([100.0, 100.0, 20.0])
    for _ in range(scans):
        scan, _ = lidar.scan(0.0, p, np.eye(3))
        sensed.integrate(scan, _state(p), 0.1)
    return sensed, p


def test_an_unmapped_building_enters_the_fused_map_and_a_phantom_leaves_it():
    sensed, _ = _mapped()
    fused = sensed.fused()
    assert sensed.cleared_parts == (1,)  # PHANTOM: the prior's second part
    probe_unmapped = np.array([[100.0, 125.1, 10.0]])  # just inside the unmapped building's face seen
    probe_phantom = np.array([[100.0, 70.0, 10.0]])
    assert fused.obstacle_clearance_m(probe_unmapped)[0] <= 0.0
    assert sensed.prior.obstacle_clearance_m(probe_unmapped)[0] > 0.0
    assert fused.obstacle_clearance_m(probe_phantom)[0] > 0.0
    # the known building stays as the prior has it, not as voxels: no sensed box stands on its faces
    sensed_parts = [b for b in fused.buildings if b.id > 3]
    assert sensed_parts
    assert all(abs(b.center_xy_m[0] - 150.0) > 10.0 or abs(b.center_xy_m[1] - 100.0) > 10.0 for b in sensed_parts)


def test_nothing_sensed_leaves_the_prior_as_it_is():
    prior = BuildingMap([KNOWN], LO, HI)
    lidar = Lidar(VLP16, RayCaster(prior), np.random.default_rng(1))
    sensed = SensedMap(prior, MappingConfig(), VLP16.max_range_m)
    p = np.array([100.0, 100.0, 20.0])
    update = sensed.integrate(lidar.scan(0.0, p, np.eye(3))[0], _state(p), 0.1)
    assert not update.changed
    assert sensed.fused() is prior


def test_an_estimate_off_in_height_does_not_raise_the_ground_into_obstacles():
    """A 0.6 m height error puts grazing ground returns metres short of the prior's ground along their beams: with the
    estimate's σ stated, the ground band and the front tolerance widen by 3 σ and nothing is marked."""
    prior = BuildingMap([KNOWN], LO, HI)
    lidar = Lidar(VLP16, RayCaster(prior), np.random.default_rng(2))
    p = np.array([100.0, 100.0, 20.0])
    scan, _ = lidar.scan(0.0, p, np.eye(3))
    placed = _state(p + [0.0, 0.0, 0.6])
    assert not SensedMap(prior, MappingConfig(), VLP16.max_range_m).integrate(scan, placed, 0.25).changed
    assert SensedMap(prior, MappingConfig(), VLP16.max_range_m).integrate(scan, placed, 0.0).changed  # σ unstated


def test_a_stamped_scan_is_placed_on_its_own_pose_not_on_the_newer_estimate():
    """A scan taken before a yaw of 10 degrees and handed over after it: placed on the decision's estimate, the known
    building's returns land metres beside it and are marked; placed on the scan's own stamp, nothing is."""
    prior = BuildingMap([KNOWN], LO, HI)
    lidar = Lidar(VLP16, RayCaster(prior), np.random.default_rng(4))
    p = np.array([100.0, 100.0, 20.0])
    scan, _ = lidar.scan(0.0, p, np.eye(3))
    turned = _state(p)
    half = np.radians(10.0) / 2.0
    turned[6:10] = (np.cos(half), 0.0, 0.0, np.sin(half))  # the vehicle yawed since the scan
    stamped = replace(scan, pose_estimate=np.array([*p, 1.0, 0.0, 0.0, 0.0]))
    assert SensedMap(prior, MappingConfig(), VLP16.max_range_m).integrate(scan, turned, 0.1).changed
    assert not SensedMap(prior, MappingConfig(), VLP16.max_range_m).integrate(stamped, turned, 0.1).changed


def test_coarser_columns_cover_every_voxel_in_fewer_boxes():
    rng = np.random.default_rng(3)
    vox = np.floor(rng.uniform((0.0, 0.0, 0.0), (40.0, 40.0, 15.0), (400, 3))) + 0.5
    fine = column_boxes(vox, 1.0, 0, np.zeros(3), np.full(3, 50.0))
    coarse = column_boxes(vox, 2.0, 0, np.zeros(3), np.full(3, 50.0))
    assert len(coarse) < len(fine)
    inside = BuildingMap(coarse, np.zeros(3), np.full(3, 50.0)).obstacle_clearance_m(vox + [0.0, 0.0, 0.49])
    assert np.all(inside <= 0.0)  # each voxel's top corner-to-centre column lies inside a box


def test_the_same_scans_give_the_same_map():
    a, _ = _mapped(2)
    b, _ = _mapped(2)
    assert a.fused().buildings == b.fused().buildings


def test_columns_merge_into_boxes_without_closing_the_space_between():
    vox = np.array([[0.5, 0.5, 3.5], [1.5, 0.5, 3.5], [0.5, 1.5, 3.5], [1.5, 1.5, 3.5], [2.5, 0.5, 1.5],
                    [5.5, 5.5, 0.5]])
    boxes = column_boxes(vox, 1.0, 100, np.zeros(3), np.full(3, 10.0))
    assert [(b.center_xy_m, b.size_xy_m, b.height_m) for b in boxes] == [
        ((1.0, 1.0), (2.0, 2.0), 4.0), ((2.5, 0.5), (1.0, 1.0), 2.0), ((5.5, 5.5), (1.0, 1.0), 1.0)]
    assert [b.id for b in boxes] == [100, 101, 102]


@pytest.mark.parametrize("fit_m, proud_m", [(0.25, 1.3), (0.0, 2.9)])
def test_a_wall_at_an_angle_to_the_grid_stands_where_its_returns_fell(fit_m, proud_m):
    """An unmapped building turned 30 degrees to the grid, seen from one side: every return is inside a sensed box,
    and the boxes' outer corners stand at most `proud_m` off the wall: 1.3 m with footprints fitted to the returns
    (1.23 m measured), over 2 m with whole squares (2.66 m: up to a 2 m square's diagonal and a voxel's)."""
    wall = Building(2, (100.0, 140.0), (40.0, 10.0), 30.0, yaw_rad=np.radians(30.0))
    world, prior = BuildingMap([wall], LO, HI), BuildingMap([], LO, HI)
    lidar = Lidar(VLP16, RayCaster(world), np.random.default_rng(0))
    sensed = SensedMap(prior, MappingConfig(column_fit_m=fit_m), VLP16.max_range_m)
    p = np.array([100.0, 100.0, 20.0])
    scan, _ = lidar.scan(0.0, p, np.eye(3))
    sensed.integrate(scan, _state(p), 0.1)
    boxes = sensed.fused().buildings
    assert boxes
    hits = p + scan.directions_body[np.isfinite(scan.ranges_m)] * scan.ranges_m[np.isfinite(scan.ranges_m), None]
    hits = hits[hits[:, 2] > 1.0]
    assert np.all(BuildingMap(boxes, LO, HI).obstacle_clearance_m(hits) <= 1e-9)
    corners = np.array([[*c, 10.0] for b in boxes for c in b.footprint_xy_m()])
    proud = world.obstacle_clearance_m(corners)
    assert proud.max() <= proud_m
    assert bool(proud.max() > 2.0) is (fit_m == 0.0)


def test_returns_beyond_the_flight_volume_make_no_box():
    """The last column of a volume 9 m wide overhangs it by 1 m (2 m columns): returns there are outside it."""
    vox = np.array([[9.5, 1.5, 0.5], [7.5, 1.5, 0.5]])
    footprints = np.array([[9.2, 1.2, 9.8, 1.8], [7.2, 1.2, 7.8, 1.8]])
    boxes = column_boxes(vox, 2.0, 0, np.zeros(3), np.array([9.0, 9.0, 9.0]), footprints, 0.25)
    assert [(b.center_xy_m, b.size_xy_m) for b in boxes] == [((7.5, 1.5), (1.0, 1.0))]


def test_voxel_keys_pack_and_unpack():
    keys = np.array([[0, 0, 0], [-5, 7, 300], [1000, -1000, -3]])
    assert np.array_equal(unpack_keys(pack_keys(keys)), keys)


@pytest.mark.parametrize("bad", [{"resolution_m": 0.0}, {"carve_stride": 0}, {"through_tolerance_m": float("nan")},
                                 {"column_m": 1.5}, {"column_fit_m": 0.3}, {"column_fit_m": -0.25}])
def test_bad_mapping_settings_are_named(bad):
    with pytest.raises(ValueError, match=next(iter(bad))):
        MappingConfig(**bad)


def test_voxels_beside_a_prior_part_grow_it_and_voxels_farther_off_stand_as_columns():
    """A survey error (the building 2 m wider and 5 m taller than the prior has it: its face seen along the whole
    side) grows the prior part; an obstacle 10 m off stays a column of its own."""
    part = Building(7, (50.0, 50.0), (10.0, 10.0), 20.0, yaw_rad=0.3)
    co, si = np.cos(0.3), np.sin(0.3)
    along = np.arange(-4.5, 5.0, 1.0)
    beside = np.column_stack([50.0 + 6.5 * co - along * si, 50.0 + 6.5 * si + along * co,
                              np.full(along.size, 24.5)])  # 1.5 m off its +x face, above its roof
    apart = np.array([[50.0 + 16.5 * co, 50.0 + 16.5 * si, 10.5]])
    grown, attached = grown_parts((part,), np.vstack([beside, apart]), 1.0, 3.0, 10.0)
    assert attached.tolist() == [True] * along.size + [False]
    g = grown[0]
    assert g.id == 7 and g.yaw_rad == part.yaw_rad and g.height_m == pytest.approx(25.0)
    assert g.size_xy_m[0] == pytest.approx(12.0) and g.size_xy_m[1] == pytest.approx(part.size_xy_m[1], abs=0.8)
    bmap = BuildingMap(list(grown), LO, HI)
    assert (bmap.obstacle_clearance_m(beside) <= 0.0).all() and bmap.obstacle_clearance_m(apart)[0] > 0.0
    # the part's own footprint is still covered
    assert bmap.obstacle_clearance_m(np.array([[50.0 - 4.9 * co, 50.0 - 4.9 * si, 19.0]]))[0] <= 0.0
    # far above its roof: not the part's (a crane's jib over it)
    _, attached = grown_parts((part,), np.array([[50.0, 50.0, 45.5]]), 1.0, 3.0, 10.0)
    assert not attached.any()


def test_an_unmapped_neighbour_beside_a_long_side_does_not_swell_the_part():
    """An unmapped building 2 m off a prior part's 40 m side, seen along 8 m of it, and taller: its voxels stand as
    columns; the part keeps its footprint and height. Returns on the part's own roof still attach."""
    part = Building(3, (0.0, 0.0), (40.0, 12.0), 20.0)
    neighbour = np.array([[8.5 + k, 8.5, 27.5] for k in range(8)])  # 2.5 m off the north face, 7.5 m above the roof
    roof = np.array([[0.5, 0.5, 21.5]])
    grown, attached = grown_parts((part,), np.vstack([neighbour, roof]), 1.0, 3.0, 10.0)
    assert attached.tolist() == [False] * len(neighbour) + [True]
    assert grown[0].size_xy_m == pytest.approx((40.0, 12.0)) and grown[0].center_xy_m == pytest.approx((0.0, 0.0))
    assert grown[0].height_m == pytest.approx(22.0)
    # the same face seen along 24 of the 40 m (a building surveyed 2.5 m off): the part grows north to cover it
    shifted = np.array([[-11.5 + k, 8.5, 17.5] for k in range(24)])
    grown, attached = grown_parts((part,), shifted, 1.0, 3.0, 10.0)
    assert attached.all() and grown[0].size_xy_m == pytest.approx((40.0, 15.0))
    with pytest.raises(ValueError, match="attach_cover"):
        MappingConfig(attach_cover=1.5)


def test_what_the_highest_beam_hits_is_held_taller_by_a_bound_and_a_prior_part_keeps_its_height():
    """From low down, the lidar's highest beam (15 deg) ends on the faces of an unmapped building and of a prior part
    the survey drew 2 m too narrow: the unmapped one's columns are held `open_above_m` above the hit (not to the
    flight volume's top), the prior part grows sideways and keeps the prior's height."""
    narrow = Building(1, (151.0, 100.0), (18.0, 20.0), 40.0)  # KNOWN as surveyed: west face 2 m off
    world = BuildingMap([KNOWN, UNMAPPED], LO, HI)
    prior = BuildingMap([narrow], LO, HI)
    lidar = Lidar(VLP16, RayCaster(world), np.random.default_rng(0))
    config = MappingConfig(open_above_m=10.0)
    sensed = SensedMap(prior, config, VLP16.max_range_m, VLP16.vertical_fov_deg[1])
    p = np.array([100.0, 100.0, 5.0])
    for _ in range(3):
        scan, _ = lidar.scan(0.0, p, np.eye(3))
        sensed.integrate(scan, _state(p), 0.1)
    fused = sensed.fused()
    grown = next(b for b in fused.buildings if b.id == 1)
    assert grown.height_m == 40.0 and grown.center_xy_m[0] - 0.5 * grown.size_xy_m[0] <= 140.5
    columns = [b for b in fused.buildings if b.id > 1]
    assert columns and all(abs(b.center_xy_m[0] - 100.0) < 10.0 and b.center_xy_m[1] > 120.0 for b in columns)
    top_hit = 5.0 + 25.0 * np.tan(np.radians(15.0))  # the highest beam on the unmapped west face, 25 m off
    tallest = max(b.height_m for b in columns)
    assert top_hit + config.open_above_m - 1.0 <= tallest <= top_hit + config.open_above_m + 2.0 * config.column_m
    assert tallest < HI[2] - 10.0
    # by default what lies above is free, as all unseen space: the columns end at the highest return
    default = SensedMap(prior, MappingConfig(), VLP16.max_range_m, VLP16.vertical_fov_deg[1])
    for _ in range(3):
        scan, _ = lidar.scan(0.0, p, np.eye(3))
        default.integrate(scan, _state(p), 0.1)
    assert max(b.height_m for b in default.fused().buildings if b.id > 1) <= top_hit + 2.0 * config.column_m


def test_an_open_column_is_never_held_above_where_the_vehicle_flew_over_it():
    from planners.sensed_map import _open_columns

    voxels = np.array([[0.5, 0.5, 10.5], [5.5, 0.5, 10.5]])
    open_top = pack_keys(np.array([[0, 0, 10], [5, 0, 10]]))
    raised = _open_columns(voxels, open_top, 1.0, 80.0, 10.0, {(0, 0): 15.0})
    tops = {tuple(v[0:2]): v[2] for v in raised[np.argsort(raised[:, 2])]}
    assert tops[(0.5, 0.5)] == 14.5 and tops[(5.5, 0.5)] == 20.5  # capped under the flight; the other held 10 m up


def test_columns_widen_to_a_large_vehicles_radius_in_whole_voxels():
    from planners.sensed_map import scaled_to_vehicle

    config = MappingConfig()
    assert scaled_to_vehicle(config, 0.42) == config  # a small quad keeps the configured columns
    assert scaled_to_vehicle(config, 6.0).column_m == 6.0 and scaled_to_vehicle(config, 6.7).column_m == 6.0


def test_a_prior_part_surveyed_a_little_long_stays_though_beams_pass_its_overhang():
    """The survey has a building 3 m longer than it stands: returns from the real end face lie 3 m beyond the
    surveyed one but inside the surveyed part, and confirm it; a few beams pass through the overhang. It stays
    (taken out whole, the pilot once flew into the real building). Without the ratio rule it would go."""
    real = Building(4, (130.0, 100.0), (40.0, 12.0), 35.0)
    surveyed = Building(4, (128.5, 100.0), (43.0, 12.0), 35.0)  # its -x end 3 m beyond the real one's
    world = BuildingMap([real], LO, HI)
    prior = BuildingMap([surveyed], LO, HI)
    lidar = Lidar(VLP16, RayCaster(world), np.random.default_rng(3))
    p = np.array([95.0, 92.0, 20.0])  # off the overhanging end: its beams cross the overhang and its faces
    for cfg, kept in ((MappingConfig(), True), (MappingConfig(confirm_ratio=1e9, core_inset_m=1e-3), False)):
        sensed = SensedMap(prior, cfg, VLP16.max_range_m)
        for _ in range(4):
            sensed.integrate(lidar.scan(0.0, p, np.eye(3))[0], _state(p), 0.1)
        # beams did pass through the overhang; the many ending beyond the surveyed end face, on the real one inside
        # the surveyed part, confirm it
        assert cfg.clear_beams <= sensed._through[0] < 0.1 * sensed._confirmed[0]
        assert (sensed.cleared_parts == ()) == kept
        if kept:  # the real building is in the map the pilot plans on
            inside = np.array([[112.0, 100.0, 10.0]])
            assert sensed.fused().obstacle_clearance_m(inside)[0] <= 0.0


def test_a_confirm_ratio_must_be_positive():
    with pytest.raises(ValueError, match="confirm_ratio"):
        MappingConfig(confirm_ratio=0.0)


def test_a_prior_part_surveyed_too_tall_stays_though_beams_pass_over_the_real_roof():
    """The survey has a building 12 m taller than it stands: seen from above its real roof, beams pass over that roof
    roof through the surveyed top, and few end on its faces yet. It stays as surveyed (taken out, the pilot once lost
    a real building this way); a phantom, seen through at every height, goes (first test)."""
    real = Building(5, (160.0, 100.0), (20.0, 20.0), 30.0)
    surveyed = Building(5, (160.0, 100.0), (20.0, 20.0), 42.0)
    behind = Building(6, (190.0, 100.0), (6.0, 80.0), 70.0)  # returns the beams that pass over the real roof
    world = BuildingMap([real, behind], LO, HI)
    prior = BuildingMap([surveyed, behind], LO, HI)
    lidar = Lidar(VLP16, RayCaster(world), np.random.default_rng(4))
    p = np.array([120.0, 100.0, 45.0])
    sensed = SensedMap(prior, MappingConfig(), VLP16.max_range_m)
    for _ in range(3):
        sensed.integrate(lidar.scan(0.0, p, np.eye(3))[0], _state(p), 0.1)
    assert sensed._through[0] >= MappingConfig().clear_beams > sensed._through_core[0]
    assert sensed.cleared_parts == ()
    assert sensed.fused().obstacle_clearance_m(np.array([[160.0, 100.0, 20.0]]))[0] <= 0.0


def test_a_surveyed_face_standing_proud_of_the_building_is_moved_in_to_it():
    """The survey has a building 3 m off towards the vehicle (the `wrong` preset's shift): the returns on its real
    face land 3 m behind the surveyed one, inside the part. The wall is moved in to them (less 3 sigma), so the
    street in front is open again, and the real building stays whole; without the rule the surveyed face stands."""
    real = Building(4, (130.0, 100.0), (20.0, 12.0), 30.0)
    surveyed = Building(4, (127.0, 100.0), (20.0, 12.0), 30.0)  # its -x face 3 m proud of the real one
    world, prior = BuildingMap([real], LO, HI), BuildingMap([surveyed], LO, HI)
    lidar = Lidar(VLP16, RayCaster(world), np.random.default_rng(5))
    p = np.array([95.0, 100.0, 15.0])
    proud = np.array([[118.0, 100.0, 10.0]])  # between the surveyed and the real -x face
    for cfg, moved in ((MappingConfig(), True), (MappingConfig(face_returns=0), False)):
        sensed = SensedMap(prior, cfg, VLP16.max_range_m)
        for _ in range(3):
            sensed.integrate(lidar.scan(0.0, p, np.eye(3))[0], _state(p), 0.1)
        fused = sensed.fused()
        assert (fused.obstacle_clearance_m(proud)[0] > 0.0) == moved
        inside_real = np.array([[120.05, 100.0, 10.0], [136.9, 105.9, 29.9], [130.0, 94.1, 0.5]])  # and surveyed
        assert np.all(fused.obstacle_clearance_m(inside_real) <= 0.0)  # never cut into the building
        moves = sensed.face_moves_m()[0]
        if moved:  # only the -x wall, by the 3 m less 3 sigma and the range noise
            assert np.count_nonzero(moves) == 1 and 2.5 <= moves.max() <= 3.0


def test_beams_over_a_roof_surveyed_too_high_do_not_move_the_wall_they_entered_by():
    """Seen from beside and above, beams enter a part surveyed 12 m too tall by the top of its wall and end on its
    real roof at every depth behind that wall: no plane parallel to the wall explains them, and the wall, confirmed
    lower down, stays where it was surveyed (moved in, it would cut the real building)."""
    real = Building(5, (160.0, 100.0), (20.0, 20.0), 30.0)
    surveyed = Building(5, (160.0, 100.0), (20.0, 20.0), 42.0)
    known = Building(6, (120.0, 60.0), (10.0, 10.0), 40.0)
    world, prior = BuildingMap([real, known], LO, HI), BuildingMap([surveyed, known], LO, HI)
    lidar = Lidar(VLP16, RayCaster(world), np.random.default_rng(6))
    sensed = SensedMap(prior, MappingConfig(), VLP16.max_range_m)
    for p in (np.array([100.0, 100.0, 45.0]), np.array([160.0, 160.0, 48.0])):
        for _ in range(3):
            sensed.integrate(lidar.scan(0.0, p, np.eye(3))[0], _state(p), 0.1)
    assert sensed._face_hits[0].sum() > 500  # many returns behind the surveyed walls
    assert np.all(sensed.face_moves_m() == 0.0)
    assert sensed.fused().buildings[0] == surveyed


def _held_by_search(sensed: SensedMap) -> np.ndarray:
    """Every key the octree holds occupied, searched one by one (what `occupied_voxels_m` caches)."""
    centres = (unpack_keys(sensed._keys) + 0.5) * sensed.config.resolution_m
    held = []
    for c in centres:
        try:
            held.append(sensed._tree.isNodeOccupied(sensed._tree.search(c)))
        except octomap.NullPointerException:
            held.append(False)
    return centres[np.asarray(held, dtype=bool)]


def test_the_occupied_voxels_searched_again_only_where_scans_reached_are_the_octrees():
    """Voxels marked from an estimate 2.5 m off (in front of a face), then carved by scans on the right pose nearby,
    and scans far off that change nothing there: after each, the cached answer is the one every key searched
    gives."""
    world = BuildingMap([KNOWN, UNMAPPED], LO, HI)
    prior = BuildingMap([KNOWN], LO, HI)
    lidar = Lidar(VLP16, RayCaster(world), np.random.default_rng(4))
    sensed = SensedMap(prior, MappingConfig(carve_stride=4), VLP16.max_range_m)
    poses = [(np.array([100.0, 112.0, 15.0]), np.array([100.0, 109.5, 15.0]))] * 2
    poses += [(np.array([100.0, 112.0 - 0.5 * k, 15.0]),) * 2 for k in range(8)]
    poses += [(np.array([20.0, 20.0, 15.0]),) * 2, (np.array([100.0, 110.0, 15.0]),) * 2]
    counts = []
    for k, (true, est) in enumerate(poses):
        scan, _ = lidar.scan(0.0, true, np.eye(3))
        sensed.integrate(replace(scan, pose_estimate=None), _state(est), 0.05)
        if k % 2 == 1 or k == len(poses) - 1:
            got = sensed.occupied_voxels_m()
            want = _held_by_search(sensed)
            assert np.array_equal(got, want)
            counts.append(len(got))
    assert max(counts) > counts[-1] > 0  # carving took some out: the cache was tested on a change
