"""The map backend keeps one scale of its own with `--scale none` (issue 23, part A): steps the map cannot
place take the map's speed, never a unit length; the scale series is recorded and read back from the .rrd;
with ground-truth scale the series sits at 1."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import cv2
import numpy as np
import pytest
from cli_helpers import vslam

from vslam.rrd.read import read_entity
from vslam_core.config import EngineConfig, PoseConfig
from vslam_core.mapping.map import Map
from vslam_core.mapping.map_scale import (
    INITIAL_SPEED,
    STARTING_REASONS,
    MapSpeed,
    median_ray_angle,
    retriangulate,
    translation_parallax,
)
from vslam_core.mapping.tracking import MapTracking
from vslam_core.pipeline import run_odometry
from vslam_core.results import FrameResult, KeyframeInserted, TrackingMode
from vslam_core.scale import TwoView, UnitScale
from vslam_core.sources.base import FrameRange, rebase_poses
from vslam_core.sources.faults import FaultInjector, parse_faults
from vslam_core.sources.kitti import KittiSource
from vslam_core.sources.open import open_source
from vslam_core.sources.synthetic import SyntheticStreet
from vslam_core.trajectory.io import read_kitti_poses
from vslam_core.trajectory.metrics import ate, kitti_errors, sim3_aligned

#: KITTI 05 frames 0:150: ~150 m, a turn at frames 116–153 (05 ground truth agrees with its images).
FRAMES = (0, 200)  # KITTI 05: its sharp turn (frames 116-153) is where the scale used to jump
EMPTY = np.zeros((0, 3))


def at(x: float) -> np.ndarray:
    pose = np.eye(4)
    pose[2, 3] = x
    return pose


def test_map_speed_measures_steps_in_map_units() -> None:
    speed = MapSpeed(frames=3)
    assert speed.step_length(TwoView(0, 1, EMPTY, EMPTY[:, :2]))[0] == INITIAL_SPEED
    for position, z in enumerate([0.0, 2.0, 4.0, 6.5]):
        speed.observe(position, at(z), measured=True)
    assert speed.speed == pytest.approx(2.0)  # median of 2, 2, 2.5
    # a step over 3 frames (the front end's keyframe 3 frames back) is 3 frames of that speed
    assert speed.step_length(TwoView(4, 7, EMPTY, EMPTY[:, :2]))[0] == pytest.approx(6.0)
    speed.observe(4, at(100.0), measured=False)  # a pose chained from the speed itself measures nothing
    speed.observe(6, at(104.0), measured=True)  # 2 frames later: 2 a frame
    assert speed.speed == pytest.approx(2.0)


def test_translation_parallax_ignores_rotation() -> None:
    K = np.array([[700.0, 0, 600], [0, 700, 180], [0, 0, 1]])  # noqa: N806
    rng = np.random.default_rng(0)
    points = rng.uniform([-10, -2, 10], [10, 2, 40], (50, 3))
    turn = np.eye(4)
    angle = np.radians(8.0)
    turn[:3, :3] = [[np.cos(angle), 0, np.sin(angle)], [0, 1, 0], [-np.sin(angle), 0, np.cos(angle)]]

    def pixels(pose: np.ndarray) -> np.ndarray:
        camera = (points - pose[:3, 3]) @ pose[:3, :3]
        return camera[:, :2] / camera[:, 2:] * 700 + [600, 180]

    assert translation_parallax(np.eye(4), turn, pixels(turn), pixels(np.eye(4)), K) < 1e-6  # 8° turn: no parallax
    moved = turn.copy()
    moved[:3, 3] = [0, 0, 1.0]
    assert translation_parallax(np.eye(4), moved, pixels(moved), pixels(np.eye(4)), K) > 5.0


def run(kitti_root: Path, out: Path, scale: str, frames: tuple[int, int] = FRAMES,
        ) -> tuple[Path, np.ndarray, np.ndarray]:
    rrd, trajectory = out / f"{scale}.rrd", out / f"{scale}.txt"
    result = vslam("run", kitti_root, "--sequence", "05", "--frames", f"{frames[0]}:{frames[1]}", "--backend", "map",
                   "--scale", scale, "--detail", "summary", "-o", rrd, "--trajectory-out", trajectory)
    assert result.returncode == 0, result.stderr
    gt = rebase_poses(read_kitti_poses(kitti_root / "poses" / "05.txt", max_rows=frames[1])[frames[0]:])
    return rrd, read_kitti_poses(trajectory), gt


@pytest.fixture(scope="module")
def unit_run(kitti_root: Path, tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, np.ndarray, np.ndarray]:
    return run(kitti_root, tmp_path_factory.mktemp("map_none"), "none")


def series(rrd: Path, entity: str) -> tuple[np.ndarray, np.ndarray]:
    table = read_entity(rrd, entity)
    return np.array(table["frame"].to_list()), np.array([v[0] for v in table["Scalars:scalars"].to_list()])


@pytest.mark.kitti
def test_scale_none_keeps_the_maps_scale(unit_run: tuple[Path, np.ndarray, np.ndarray]) -> None:
    """The trajectory has the right shape (Sim(3)-aligned t_err) and one scale: the step over the ground
    truth's, read back from the recording, stays within a narrow band over the whole window, a sharp turn
    included. Before bundle adjustment held the front end's two-view rotations between keyframes, the scale
    fell by 10 % in the turn (t_err 1.7 %, band 1.20); unit steps chained frame by frame gave 8.6 % on 0:300.
    1.19 % with the front end's rotations at a fixed sigma, 1.22 % since they are loose where ambiguous (the
    KITTI --scale none rows of the matrix: 0.385 -> 0.354 m at step 1, docs/matrix.md)."""
    rrd, poses, gt = unit_run
    aligned_t, _ = kitti_errors(gt, sim3_aligned(gt, poses))
    assert aligned_t < 1.3, aligned_t
    frames, steps = series(rrd, "/metrics/map_scale/step")
    ratio_frames, ratios = series(rrd, "/metrics/map_scale/step_over_truth")
    assert len(frames) >= 140 and set(ratio_frames) <= set(frames)
    truth = np.linalg.norm(np.diff(gt[:, :3, 3], axis=0), axis=1)
    np.testing.assert_allclose(ratios, steps[np.isin(frames, ratio_frames)] / truth[ratio_frames - 1], rtol=1e-5)
    settled = ratios[ratio_frames >= 20]  # after the map's first keyframes
    low, high = np.percentile(settled, [5, 95])
    assert high / low < 1.15, (low, high)  # unit steps would follow the car's speed instead


@pytest.mark.kitti
def test_scale_gt_series_sits_at_one(kitti_root: Path, tmp_path: Path) -> None:
    rrd, _, _ = run(kitti_root, tmp_path, "gt", frames=(0, 80))  # a shorter window than the unit run's
    _, ratios = series(rrd, "/metrics/map_scale/step_over_truth")
    assert len(ratios) >= 70
    assert abs(np.median(ratios) - 1.0) < 0.02
    legend = read_entity(rrd, "/metrics/map_scale/step_over_truth", static=True)["SeriesLines:names"].to_list()
    assert legend[-1] == ["step length estimate / truth (ground truth given)"]


@pytest.fixture(scope="module")
def blurred_unit_run(kitti_root: Path) -> list[FrameResult]:
    """KITTI 05 0:80 with frames 60–62 blurred, --backend map --scale none: the frames' results. Its first 60 are
    those of a run over KITTI 05 0:N, N ≤ 60, unblurred (the map backend is causal: measured for 0:25 and 0:40,
    the same keyframes and poses bit for bit), so the tests of the map's start read them from here."""
    source = FaultInjector(KittiSource(kitti_root, sequence="05", frames=FrameRange(0, 80)), parse_faults("blur@60:62"))
    results: list[FrameResult] = []
    run_odometry(source, EngineConfig(backend="map", scale="none", threads=1), (lambda _, r: results.append(r),))
    return results


@pytest.mark.kitti
def test_frames_the_map_cannot_place_take_the_maps_speed(blurred_unit_run: list[FrameResult]) -> None:
    """KITTI 05 0:80 with frames 60–62 blurred, --scale none: the map was initialised at one unit a frame
    while the car drove 0.6 m a frame, and it drives ~1.07 m a frame by frame 40, so the map moves ~1.8 units a
    frame there. The blurred frames are dead-reckoned with that speed, not with unit steps."""
    results = blurred_unit_run
    centres = np.array([r.T_world_cam[:3, 3] for r in results])
    steps = np.linalg.norm(np.diff(centres, axis=0), axis=1)  # steps[i - 1]: frame i - 1 → i, as tracked
    modes = [r.mapping.mode if r.mapping is not None else None for r in results]
    mapped = [steps[i - 1] for i in range(45, 60) if modes[i] == TrackingMode.MAP and modes[i - 1] == TrackingMode.MAP]
    coasted = [steps[i - 1] for i in range(60, 63) if modes[i] == TrackingMode.COASTED]
    assert len(mapped) >= 10 and coasted, modes[40:70]
    speed = float(np.median(mapped))
    assert speed > 1.4  # the map's unit is not the car's metre: a unit step would be far off
    np.testing.assert_allclose(coasted, speed, rtol=0.25)


def bundle_adjusted_step_changes(results: list[FrameResult]) -> np.ndarray:
    """Per bundle adjustment, per pair of consecutive window keyframes: the distance between them after it over
    the distance before (each keyframe's pose before = at its insertion or after the last BA that moved it)."""
    poses: dict[int, np.ndarray] = {}
    changes = []
    for result in results:
        mapping = result.mapping
        if mapping is None:
            continue
        adjusted = mapping.bundle_adjustment
        if adjusted is not None:
            after = dict(zip(adjusted.keyframe_ids.tolist(), adjusted.keyframe_poses, strict=True))
            for k, pose in after.items():
                if k - 1 in after and k in poses and k - 1 in poses:
                    before = np.linalg.norm(poses[k][:3, 3] - poses[k - 1][:3, 3])
                    changes.append(np.linalg.norm(pose[:3, 3] - after[k - 1][:3, 3]) / before)
            poses.update(after)
        if mapping.keyframe is not None:
            poses[mapping.keyframe.keyframe_id] = mapping.keyframe.T_world_cam
    return np.array(changes)


@pytest.mark.kitti
def test_bundle_adjustment_keeps_the_maps_steps(blurred_unit_run: list[FrameResult], kitti_root: Path) -> None:
    """With --scale none nothing outside the map holds its scale, and bundle adjustment left free lengthened
    the keyframe-to-keyframe steps a little, which added up to scale drift. Each step now enters BA as a prior
    at its length before it (sigma `none_step_sigma` = 0.3 % of it). In the run above (~100 steps adjusted) the
    largest change a BA makes is 0.95 % and the 95th percentile 0.38 %; the same run without the prior: 3.53 %
    and 0.65 % (with rays at 3°, before `none_min_triangulation_deg` = 3.5: 0.22 / 0.12 % and 1.91 / 0.38 %;
    the largest changes now come from the first adjustments after the map starts, on fewer landmarks)."""
    held = np.abs(bundle_adjusted_step_changes(blurred_unit_run) - 1)
    config = EngineConfig(backend="map", scale="none", threads=1)
    free: list[FrameResult] = []
    source = FaultInjector(KittiSource(kitti_root, sequence="05", frames=FrameRange(0, 80)), parse_faults("blur@60:62"))
    run_odometry(source, replace(config, map=replace(config.map, none_step_sigma=0.0)), (lambda _, r: free.append(r),))
    loose = np.abs(bundle_adjusted_step_changes(free) - 1)
    assert len(held) >= 80 and len(loose) >= 80
    assert held.max() < 0.5 * loose.max() and held.max() < 0.012, (held.max(), loose.max())
    assert np.percentile(held, 95) < 0.75 * np.percentile(loose, 95) and np.percentile(held, 95) < 0.005


def keyframe_reasons(results: list[FrameResult]) -> list[str]:
    return [k.why for k in keyframes(results)]


@pytest.mark.kitti
def test_the_map_is_not_initialised_from_a_pure_rotation(kitti_root: Path,
                                                         blurred_unit_run: list[FrameResult]) -> None:
    """A camera turning on the spot (a real KITTI frame re-imaged through K·R·K⁻¹, 0.8° of yaw a frame) gives
    no translation parallax: with --scale none no second keyframe sets the map's scale from it, and no landmark
    is made. The same frames driven forward initialise the map within a few frames."""
    source = KittiSource(kitti_root, sequence="05", frames=FrameRange(0, 25))
    camera = source.intrinsics
    first = next(iter(source))
    config = EngineConfig(backend="map", scale="none", threads=1)
    tracking = MapTracking(camera, config, UnitScale())
    try:
        results = []
        for i in range(25):
            angle = np.radians(0.8 * i)
            rotation = np.array([[np.cos(angle), 0, np.sin(angle)], [0, 1, 0], [-np.sin(angle), 0, np.cos(angle)]])
            warp = camera.K @ rotation.T @ np.linalg.inv(camera.K)
            image = cv2.warpPerspective(first.image, warp, (camera.width, camera.height))
            results.append(tracking.process(replace(first, index=i, image=image)))
        reasons = keyframe_reasons(results)
        assert reasons[0] == "initialisation" and not [why for why in reasons if why.startswith("initialisation:")]
        assert not tracking.mapping.map.landmarks
    finally:
        tracking.close()
    reasons = keyframe_reasons(blurred_unit_run[:25])  # KITTI 05 0:25 driven forward
    assert reasons[0] == "initialisation" and reasons[1].startswith("initialisation: parallax"), reasons
    assert float(reasons[1].split()[2]) >= config.map.init_parallax_px


@pytest.mark.kitti
def test_an_initialisation_with_too_few_landmarks_is_tried_again(kitti_root: Path,
                                                                 blurred_unit_run: list[FrameResult]) -> None:
    """--scale none: the keyframe that sets the map's scale must triangulate `init_min_landmarks` landmarks; with
    fewer the next keyframe tries again (issue 23: re-initialise when the two-view start is degenerate). Before,
    any landmark counted as a map: on a hand-held-like re-imaging of KITTI 05 the first attempt made 0 and the
    next 8, and keyframes went on every 10 frames against a map PnP could never use. Here the bar is set above
    what any attempt on KITTI 05 0:40 makes, so every keyframe stays an attempt; at the default bar attempts go
    on until one reaches it (the first makes 49 landmarks, the second 141), and the next keyframe is an ordinary
    one."""
    source = KittiSource(kitti_root, sequence="05", frames=FrameRange(0, 40))
    config = EngineConfig(backend="map", scale="none", threads=1)
    unreachable: list[FrameResult] = []
    run_odometry(source, replace(config, map=replace(config.map, init_min_landmarks=100_000)),
                 (lambda _, r: unreachable.append(r),))
    attempts = keyframes(unreachable)
    assert len(attempts) >= 3, attempts
    assert all(k.why.startswith(STARTING_REASONS) for k in attempts), [k.why for k in attempts]
    assert max(k.new_landmarks for k in attempts) >= 50  # they triangulated, just not enough for this bar
    # at the default bar: KITTI 05 0:40 (the blurred run's first 40 frames, see `blurred_unit_run`)
    assert_started_once(keyframes(blurred_unit_run[:40]), config.map.init_min_landmarks)



@pytest.mark.kitti
def test_a_car_pulling_away_starts_its_map_where_its_landmarks_say(kitti_root: Path) -> None:
    """KITTI 05 from frame 150 at every 3rd frame, --scale none: the car pulls away, and the map's first attempt
    (the 5th frame) triangulates too few landmarks, the second (the 8th) starts the map. The attempt's keyframe and
    the frames before it were chained at the map's guessed speed while the car accelerated (each frame's distance
    from the first, over the truth's, 1.32 / 1.26 / 1.19 / 1.13 / 1.09 times the 8th frame's at frames 1-5), and
    the map carried it (t_err 1.95 % over 150:300:3, 0.90 % at every frame). Once the map starts they are placed
    against its landmarks (`map_scale.place_attempts`, `FramesBeforeMap`): measured 0.94, then 1.00-1.01. The
    summary says so: 6 of the frames counted as two-view (their tracking-time mode) were placed again."""
    source = KittiSource(kitti_root, sequence="05", frames=FrameRange(150, 195, 3))
    results: list[FrameResult] = []
    run = run_odometry(source, EngineConfig(backend="map", scale="none", threads=1), (lambda _, r: results.append(r),))
    made = keyframes(results)
    bar = EngineConfig().map.init_min_landmarks
    assert [k.position for k in made[:3]] == [0, 5, 8] and made[1].new_landmarks < bar <= made[2].new_landmarks
    assert source.ground_truth is not None
    estimate, truth = (np.linalg.norm(p[1:, :3, 3] - p[0, :3, 3], axis=1)
                       for p in (run.pose_array(), source.ground_truth))
    ratio = estimate / truth / (estimate[7] / truth[7])  # over the map's own scale at its start (frame 8)
    assert abs(ratio[0] - 1) < 0.1 and np.all(np.abs(ratio[1:] - 1) < 0.03), ratio.round(3)
    assert 0 < run.placed_at_map_start <= run.modes[TrackingMode.TWO_VIEW]
    assert f"; {run.placed_at_map_start} frames tracked before the map started placed again by PnP" in \
        str(run.placed_summary("none"))


def test_a_moved_keyframes_landmarks_are_triangulated_again() -> None:
    """`retriangulate`: the landmarks of a keyframe placed anew lie where the rays of their first and last keyframes
    meet at the poses now, not where the chained pose had put them; `median_ray_angle` is the angle of such rays
    (two cameras 1 m apart, a point 1 m ahead of their midpoint: 2·atan(0.5) = 53.13°)."""
    K = np.array([[700.0, 0, 600], [0, 700, 180], [0, 0, 1]])  # noqa: N806
    truth = np.array([[0.3, -0.2, 8.0], [-1.0, 0.5, 12.0]])
    second = np.eye(4)
    second[:3, 3] = [0.1, 0.0, 1.5]  # where the second keyframe really is
    chained = second.copy()
    chained[:3, 3] = [0.1, 0.0, 2.5]  # where the chain had put it
    the_map = Map()
    for pose in (np.eye(4), chained):
        the_map.add_keyframe(len(the_map.keyframes), 0, pose, np.zeros(0, np.int64), np.zeros((0, 2)), None)
    for point in truth:
        pixels = [K @ (point - pose[:3, 3]) for pose in (np.eye(4), second)]
        the_map.add_landmark(np.zeros(3), {k: p[:2] / p[2] for k, p in enumerate(pixels)})
    the_map.keyframes[1].T_world_cam = second  # placed anew
    retriangulate(the_map, {1}, K, EngineConfig().map)
    np.testing.assert_allclose(the_map.positions([0, 1]), truth, atol=1e-9)
    right = np.eye(4)
    right[0, 3] = 1.0
    assert median_ray_angle(np.array([[0.5, 0.0, 1.0]]), np.eye(4), right) == pytest.approx(53.1301, abs=1e-3)


def assert_started_once(made: list[KeyframeInserted], bar: int) -> None:
    """Keyframes of one map segment, in order: attempts (starting reasons) until the first initialisation that
    triangulated `bar` landmarks, and after it keyframes made for tracking."""
    start = next(n for n, k in enumerate(made)
                 if k.why.startswith("initialisation: parallax") and k.new_landmarks >= bar)
    assert all(k.why.startswith(STARTING_REASONS) and k.new_landmarks < bar for k in made[:start]), made[:start]
    assert not made[start + 1].why.startswith(STARTING_REASONS), [k.why for k in made]


@pytest.mark.kitti
def test_a_new_map_segment_starts_its_own_map(kitti_root: Path) -> None:
    """--scale none: KITTI 00 170:240 without frames 199–208 (the sharpest turn: relocalisation fails) starts a
    second map segment, whose first keyframe is no map yet: initialisations follow, waiting for parallax, until one
    triangulates `init_min_landmarks` landmarks; only then are keyframes made for tracking again."""
    source = open_source(str(kitti_root), sequence="00", frames=FrameRange.parse("170:240"), inject="drop@199:208")
    config = EngineConfig(backend="map", scale="none", threads=1)
    results: list[FrameResult] = []
    run_odometry(source, config, (lambda _, r: results.append(r),))
    second = [r.mapping.keyframe for r in results if r.mapping and r.mapping.keyframe and r.mapping.segment == 1]
    assert second[0].why == "new map segment" and second[0].new_landmarks == 0
    assert_started_once(second, config.map.init_min_landmarks)


def keyframes(results: list[FrameResult]) -> list[KeyframeInserted]:
    return [r.mapping.keyframe for r in results if r.mapping is not None and r.mapping.keyframe is not None]


def test_a_slow_hand_held_camera_starts_its_map_from_two_views() -> None:
    """The synthetic walk (a hand-held camera at 30 Hz, 4.5 cm a frame, swinging up to 2° a frame) never gives
    its median track 20 px of translation parallax from the first frame. After `init_wait_frames` the map starts
    from the two views alone, and the frames tracked before it are placed against its first landmarks by PnP. Its
    points lie ~250 frames of travel away (`slow_depth_frames`: 100), so rays meeting at 1° make its landmarks
    (`slow_min_triangulation_deg`) and it starts 11 frames after the first (68 at 3.5°). Measured: ATE after
    Sim(3) 1.2 cm over all 100 frames (0.8 cm at 3.5°, but 9.5 cm against 1.2 cm over benchmarks.walk's 12 runs);
    before the two-view start (the frames chained at the guessed speed) 10.7 cm."""
    source = SyntheticStreet(route="walk", frames=FrameRange(0, 100))
    config = EngineConfig(backend="map", scale="none", threads=1)
    results: list[FrameResult] = []
    run = run_odometry(source, config, (lambda _, r: results.append(r),))
    started = [r.position for r in results if r.mapping is not None and r.mapping.keyframe is not None
               and r.mapping.keyframe.why.startswith("initialisation: two views")]
    assert started and config.map.init_wait_frames <= started[0] <= 30, keyframe_reasons(results)
    angles = {k.min_ray_angle_deg for k in keyframes(results) if k.position >= started[0]}
    assert angles == {config.map.slow_min_triangulation_deg}, angles  # every keyframe since: a slow camera
    truth, poses = source.ground_truth, run.pose_array()
    assert ate(truth[: started[0] + 1], poses[: started[0] + 1]) < 0.02
    assert ate(truth, poses) < 0.03
    assert all(r.mapping is not None and r.mapping.mode == TrackingMode.MAP for r in results[started[0] + 1:])


def test_the_front_end_tracks_every_frame_of_a_hand_held_walk() -> None:
    """A hand-held step (4.5 cm) is 1/100-1/400 of the street's depth: when fewer than `min_inliers` points within
    50 baselines vote in the chirality check, points up to 500 baselines away do (`pose.chirality_far_depth`), and
    `vo` holds no frame of the walk. With 50 baselines alone (cv2.recoverPose's distanceThresh) it held 60 of these
    100 frames. Measured with ground-truth scale: ATE after Sim(3) 0.8 cm (4.6 cm with 50 alone)."""
    source = SyntheticStreet(route="walk", frames=FrameRange(0, 100))
    run = run_odometry(source, EngineConfig(backend="vo", scale="gt", threads=1))
    assert run.held == 0
    assert ate(source.ground_truth, run.pose_array()) < 0.015
    fifty = EngineConfig(backend="vo", scale="gt", threads=1, pose=replace(PoseConfig(), chirality_far_depth=50.0))
    assert run_odometry(source, fifty).held >= 30
