"""The logging API (`vslam.log.FrameLog`): another pipeline's frames on real KITTI images, read back from the .rrd
with vslam's own readers (`inspect`, `check`, `crop`, `compare`) and the raw entities."""

from __future__ import annotations

import json
import subprocess
from pathlib import Path

import cv2
import numpy as np
import pytest
from cli_helpers import vslam
from rerun.chunk import RrdReader

from vslam.log import CameraIntrinsics, FrameLog
from vslam.rrd import read_entity, rerun_binary
from vslam_core.geometry import invert_pose
from vslam_core.sources.base import rebase_poses
from vslam_core.trajectory.io import read_kitti_poses

FRAMES = range(100, 130)  # KITTI 05: the car drives straight at ~1 m a frame
KINK_FRAME = 115  # the pipeline's estimate turns 2° too far here, and says so
KINK_DEG = 2.0
KITTI_05 = CameraIntrinsics(fx=707.0912, fy=707.0912, cx=601.8873, cy=183.1104, width=1226, height=370)


def _yaw(degrees: float) -> np.ndarray:
    """(4, 4) rotation about the camera's y axis (down): a turn."""
    a = np.radians(degrees)
    pose = np.eye(4)
    pose[[0, 0, 2, 2], [0, 2, 0, 2]] = np.cos(a), np.sin(a), -np.sin(a), np.cos(a)
    return pose


def estimate_with_kink(gt: np.ndarray) -> np.ndarray:
    """The ground truth's own steps, except one step that turns `KINK_DEG` further (at `KINK_FRAME`)."""
    poses = [gt[0]]
    for k in range(1, len(gt)):
        step = invert_pose(gt[k - 1]) @ gt[k]
        if FRAMES[k] == KINK_FRAME:
            step = step @ _yaw(KINK_DEG)
        poses.append(poses[-1] @ step)
    return np.array(poses)


def log_window(kitti_root: Path, path: Path, gt: np.ndarray, **options: object) -> np.ndarray:
    """Log `FRAMES` through the API: KITTI images, FAST corners, tracks of the corners into the next frame (KLT),
    every 7th track an outlier; per-frame ground truth (``gt=``). Returns the logged estimate."""
    estimate = estimate_with_kink(gt)
    fast = cv2.FastFeatureDetector_create(40)
    previous: tuple[np.ndarray, np.ndarray] | None = None
    with FrameLog(path, camera=KITTI_05, source="kitti-05", pipeline="test-vo", **options) as log:  # type: ignore[arg-type]
        for k, index in enumerate(FRAMES):
            image = cv2.imread(str(kitti_root / "sequences" / "05" / "image_0" / f"{index:06d}.png"),
                               cv2.IMREAD_GRAYSCALE)
            corners = np.array([p.pt for p in fast.detect(image)][:300], np.float32).reshape(-1, 2)
            tracks, inliers = None, None
            if previous is not None:
                moved, status, _ = cv2.calcOpticalFlowPyrLK(previous[1], image, previous[0], None)
                ok = status.reshape(-1) == 1
                ids = np.arange(len(previous[0]))[ok] + 1000 * index
                tracks = (ids, previous[0][ok], moved[ok])
                inliers = ids % 7 != 0
            kink = index == KINK_FRAME
            log.frame(index, pose=estimate[k], time=0.1 * index, image=image, corners=corners, tracks=tracks,
                      inliers=inliers, health="warn" if kink else "ok", reasons=["sharp_turn"] if kink else [],
                      scalars={"corners": len(corners)}, gt=gt[k])
            previous = (corners, image)
    return estimate


@pytest.fixture(scope="module")
def logged(kitti_root: Path, tmp_path_factory: pytest.TempPathFactory) -> dict[str, object]:
    gt = read_kitti_poses(kitti_root / "poses" / "05.txt", max_rows=FRAMES.stop)[FRAMES.start:]
    path = tmp_path_factory.mktemp("api") / "api.rrd"
    estimate = log_window(kitti_root, path, gt)
    return {"path": path, "gt": gt, "estimate": estimate}


@pytest.mark.kitti
def test_inspect_reads_health_tracks_and_drift(logged: dict[str, object]) -> None:
    path = logged["path"]
    assert isinstance(path, Path)
    result = vslam("inspect", path, "--json")
    assert result.returncode == 0, result.stderr
    report = json.loads(result.stdout)
    assert report["frames"] == {"count": 30, "first": 100, "last": 129}
    assert report["properties"]["pipeline"] == "test-vo" and report["properties"]["schema_version"] == "2"
    assert report["properties"]["frames"] == "100:130" and report["recording_name"] == "test-vo kitti-05 frames 100:130"
    assert report["flagged"] == [{"start": KINK_FRAME, "end": KINK_FRAME, "status": "warn", "reasons": ["sharp_turn"]}]
    assert report["config"] == {}  # not run by vslam's engine: no engine config is claimed
    top = report["drift"]["rotation"][0]
    assert top["frame"] == KINK_FRAME and top["deg"] == pytest.approx(KINK_DEG, abs=1e-4)  # KITTI: 1e-6 rounding
    assert top["reasons"] == ["sharp_turn"]
    assert all(e["deg"] < 1e-3 for e in report["drift"]["rotation"][1:])  # every other step is the truth's own
    assert report["series"]["tracks_alive"]["min"] > 100
    assert 0.8 < report["series"]["inlier_ratio"]["mean"] < 0.9  # 6 in 7 flagged inliers
    assert report["series"]["fb_rejected"] is None  # not reported: left out, not zero
    assert report["stages_ms"]["record"] is None  # vslam's recording time is not the pipeline's


@pytest.mark.kitti
def test_entities_hold_what_was_logged(logged: dict[str, object]) -> None:
    path, gt, estimate = logged["path"], logged["gt"], logged["estimate"]
    assert isinstance(path, Path) and isinstance(gt, np.ndarray) and isinstance(estimate, np.ndarray)
    camera = read_entity(path, "/world/camera")
    assert camera["frame"].to_list() == list(FRAMES)
    translations = np.array([t[0] for t in camera["Transform3D:translation"].to_list()])
    assert np.allclose(translations, rebase_poses(estimate)[:, :3, 3], atol=1e-5)  # world = first camera
    health = read_entity(path, "/health")
    assert [s[0] for s in health["status"].to_list()].count("warn") == 1
    flow = read_entity(path, "/world/camera/image/flow")
    classes = np.concatenate([np.array(c) for c in flow["Arrows2D:class_ids"].to_list()])
    assert set(classes.tolist()) == {3, 5}  # RANSAC outlier, inlier
    reader = RrdReader(path)
    entities = reader.store(store=reader.recordings()[0]).schema().entity_paths()
    assert not [e for e in entities if e.startswith(("/world/map", "/metrics/ba", "/loops"))]  # no map of its own
    corners = read_entity(path, "/metrics/custom/corners")
    assert corners["frame"].to_list() == list(FRAMES)
    position = read_entity(path, "/metrics/error/position_m")
    errors = np.array([v[0] for v in position["Scalars:scalars"].to_list()])
    truth = np.linalg.norm(rebase_poses(estimate)[:, :3, 3] - rebase_poses(gt)[:, :3, 3], axis=1)
    assert np.allclose(errors, truth, atol=1e-6)
    assert errors[list(FRAMES).index(KINK_FRAME)] < 1e-6 < errors[-1]  # drifts only after the kink


@pytest.mark.kitti
def test_check_crop_and_compare_work_on_it(logged: dict[str, object], tmp_path: Path) -> None:
    path = logged["path"]
    assert isinstance(path, Path)
    check = vslam("check", path)
    assert check.returncode == 0, check.stdout + check.stderr
    assert "conforms to recording schema 2" in check.stdout
    cropped = tmp_path / "cropped.rrd"
    result = vslam("crop", path, "--frames", "110:120", "-o", cropped)
    assert result.returncode == 0, result.stderr
    report = json.loads(vslam("inspect", cropped, "--json").stdout)
    assert report["frames"]["count"] == 10 and report["properties"]["cropped_from"] == "100:130"
    compared = vslam("compare", path, cropped, "-o", tmp_path / "both.rrd", "--json")
    assert compared.returncode == 0, compared.stderr
    verify = subprocess.run([rerun_binary(), "rrd", "verify", str(path)], capture_output=True, text=True, timeout=120)
    assert verify.returncode == 0, verify.stderr[-2000:]


@pytest.mark.kitti
def test_ground_truth_up_front_and_unit_scale(kitti_root: Path, tmp_path: Path) -> None:
    """``ground_truth=`` (row i = frame i) instead of ``gt=``; scale none: errors after Sim(3) alignment."""
    gt_all = read_kitti_poses(kitti_root / "poses" / "05.txt", max_rows=FRAMES.stop)
    path = tmp_path / "unit.rrd"
    with FrameLog(path, camera=KITTI_05, source="kitti-05", ground_truth=gt_all, scale="none",
                  detail="summary") as log:
        for index in FRAMES:
            pose = gt_all[index].copy()
            pose[:3, 3] *= 0.1  # a tenth of the scale: Sim(3) alignment takes it out
            log.frame(index, pose=pose)
    report = json.loads(vslam("inspect", path, "--json").stdout)
    assert report["accuracy_alignment"] == "sim3"
    assert report["accuracy"]["max_position_error_m"] < 1e-3
    assert report["flagged"] == [] and report["series"]["tracks_alive"] is None  # nothing reported, nothing invented
    assert read_entity(path, "/health").is_empty()
    assert read_entity(path, "/world/camera/image").is_empty()


def test_bad_input_is_refused_in_one_sentence(tmp_path: Path) -> None:
    path = tmp_path / "bad.rrd"
    with pytest.raises(ValueError, match="must end in .rrd"):
        FrameLog(tmp_path / "x.txt", camera=KITTI_05, source="s")
    log = FrameLog(path, camera=KITTI_05, source="s")
    with pytest.raises(ValueError, match="not a rigid transform"):
        log.frame(0, pose=np.diag([2.0, 1.0, 1.0, 1.0]))
    shifted = np.eye(4)
    shifted[:3, 3] = 5.0
    with pytest.raises(ValueError, match="corners"):  # refused: it does not become the first (world) pose
        log.frame(0, pose=shifted, corners=np.zeros((3, 3)))
    log.frame(0, pose=np.eye(4))
    with pytest.raises(ValueError, match="indices must increase"):
        log.frame(0, pose=np.eye(4))
    with pytest.raises(ValueError, match="ground truth for every frame or for none"):
        log.frame(1, pose=np.eye(4), gt=np.eye(4))
    with pytest.raises(ValueError, match="reasons need a health"):
        log.frame(2, pose=np.eye(4), reasons=["x"])
    with pytest.raises(ValueError, match="without commas"):
        log.frame(2, pose=np.eye(4), health="warn", reasons=["a,b"])
    with pytest.raises(ValueError, match="one flag per track"):
        log.frame(2, pose=np.eye(4), tracks=(np.arange(3), np.zeros((3, 2)), np.ones((3, 2))), inliers=np.ones(2))
    with pytest.raises(ValueError, match="not 'record'"):  # the recorder's own time
        log.frame(2, pose=np.eye(4), timings_ms={"record": 1.0})
    log.close()
    camera = read_entity(path, "/world/camera")
    assert camera["frame"].to_list() == [0] and list(camera["Transform3D:translation"].to_list()[0][0]) == [0, 0, 0]
    with pytest.raises(ValueError, match="no frame was logged"):
        FrameLog(tmp_path / "empty.rrd", camera=KITTI_05, source="s").close()
    assert not (tmp_path / "empty.rrd").exists()


def test_an_exception_in_the_loop_keeps_a_valid_recording(tmp_path: Path) -> None:
    path = tmp_path / "stopped.rrd"
    with pytest.raises(RuntimeError), FrameLog(path, camera=KITTI_05, source="s") as log:
        for index in range(5):
            log.frame(index, pose=np.eye(4), health="ok")
        raise RuntimeError("the pipeline crashed")
    report = json.loads(vslam("inspect", path, "--json").stdout)
    assert report["frames"]["count"] == 5
    assert report["properties"]["stopped"] == "stopped by RuntimeError after 5 frames"
