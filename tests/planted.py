"""Bugs planted in real runs on KITTI 05 (issue 54): a translation whose sign flipped, or a 3° yaw kink, in one
frame's step; the steps before and after it are the pipeline's own.

Two pipelines: vslam's engine (its run recorded by vslam's own `Recorder` with the poses from the planted frame on
re-chained, `record_vslam`), and a small ORB + essential-matrix VO of this file's own (knn matching with a ratio
test, unlike examples/orb_vo.py's cross-check) logged through `vslam.log.FrameLog` (`own_vo`, `log_own`). Each
pipeline runs once; a bug is planted when its frames are logged (the recorded step, not a run anew).
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Literal

import cv2
import numpy as np

from vslam.log import CameraIntrinsics, FrameLog, Tracks
from vslam.recording import Detail, Recorder, version_properties
from vslam_core.config import EngineConfig
from vslam_core.geometry import invert_pose
from vslam_core.pipeline import RunResult, run_odometry
from vslam_core.results import FrameResult
from vslam_core.sources.base import Frame, FrameRange
from vslam_core.sources.kitti import KittiSource

Bug = Literal["none", "flip", "kink"]
#: Where the bugs are planted: KITTI 05 frames 0:120, frame 57's step.
FRAMES, BUG_FRAME = (0, 120), 57
KINK_DEG = 3.0


def yaw(degrees: float) -> np.ndarray:
    """(3, 3) rotation about the camera's y axis (down, RDF): a turn of the car."""
    c, s = math.cos(math.radians(degrees)), math.sin(math.radians(degrees))
    return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])


def bad_step(step: np.ndarray, bug: Bug) -> np.ndarray:
    """(4, 4) step T_prev_cur with `bug`: its translation negated (flip) or its rotation turned by `KINK_DEG`."""
    out = step.copy()
    if bug == "flip":
        out[:3, 3] = -out[:3, 3]
    elif bug == "kink":
        out[:3, :3] = step[:3, :3] @ yaw(KINK_DEG)
    return out


def plant(poses: np.ndarray, position: int, bug: Bug) -> np.ndarray:
    """(N, 4, 4) T_world_cam with the step into `position` replaced by its `bad_step`, every later step kept:
    poses from `position` on are moved rigidly."""
    if bug == "none":
        return poses
    step = invert_pose(poses[position - 1]) @ poses[position]
    moved = poses[position - 1] @ bad_step(step, bug) @ invert_pose(step) @ invert_pose(poses[position - 1])
    out = poses.copy()
    out[position:] = moved @ poses[position:]
    return out


@dataclass
class _Source:
    """What the `Recorder` reads of a source: a KITTI source's facts, with or without its ground truth."""

    name: str
    intrinsics: CameraIntrinsics
    ground_truth: np.ndarray | None
    properties: dict[str, str]
    camera_height: float | None = None


@dataclass
class VslamRun:
    """vslam's engine over KITTI 05 `FRAMES` (odometry backend, scale gt): its frames (without images), results."""

    source: KittiSource
    config: EngineConfig
    frames: list[Frame]
    results: list[FrameResult]


def vslam_run(kitti_root: Path) -> VslamRun:
    source = KittiSource(kitti_root, sequence="05", frames=FrameRange(*FRAMES))
    config = EngineConfig()
    frames: list[Frame] = []
    results: list[FrameResult] = []

    def keep(frame: Frame, result: FrameResult) -> None:
        frames.append(Frame(frame.index, frame.timestamp, np.zeros((0, 0), np.uint8)))
        results.append(result)

    run_odometry(source, config, (keep,))
    return VslamRun(source, config, frames, results)


def record_vslam(run: VslamRun, path: Path, bug: Bug, with_gt: bool) -> Path:
    """`run` recorded by vslam's `Recorder` (detail summary) with `bug` planted at `BUG_FRAME`."""
    poses = plant(np.array([r.T_world_cam for r in run.results]), BUG_FRAME - FRAMES[0], bug)
    source = _Source(run.source.name, run.source.intrinsics, run.source.ground_truth if with_gt else None, {})
    properties = {"name": f"vslam kitti-05 frames {FRAMES[0]}:{FRAMES[1]} bug {bug}", "source": "kitti-05",
                  "frames": f"{FRAMES[0]}:{FRAMES[1]}", "frame_count": str(len(poses)), "scale": "gt",
                  "backend": "vo", "bug": bug, **version_properties()}
    recorder = Recorder(path, source, run.config, properties, Detail.SUMMARY)  # type: ignore[arg-type]
    result = RunResult([], [], [])
    for frame, frame_result, pose in zip(run.frames, run.results, poses, strict=True):
        recorder.log_frame(frame, dataclasses.replace(frame_result, T_world_cam=pose))
        result.indices.append(frame.index)
        result.timestamps.append(frame.timestamp)
        result.poses.append(pose)
        result.tracked += 1
    recorder.finish(result, None)
    return path


# ------------------------------------------------------------------------------------------ a VO of our own


@dataclass
class OwnStep:
    """One frame of the own VO: its rotation and unit translation (X_cur = R·X_prev + t; None: no estimate),
    matches into it and RANSAC's inlier flags."""

    R: np.ndarray | None  # noqa: N815
    t: np.ndarray | None
    tracks: Tracks | None
    inliers: np.ndarray | None
    health: Literal["ok", "warn", "fail"]
    reasons: list[str]


@dataclass
class OwnVo:
    camera: CameraIntrinsics
    times: np.ndarray  # (F,) seconds of every frame of the sequence
    gt: np.ndarray  # (F, 4, 4) T_world_cam of every frame
    steps: dict[int, OwnStep]  # frame → its step


def _kitti(root: Path) -> tuple[CameraIntrinsics, np.ndarray, np.ndarray, list[Path]]:
    folder = root / "sequences" / "05"
    p0 = next(line for line in (folder / "calib.txt").read_text().splitlines() if line.startswith("P0:"))
    fx, _, cx, _, _, fy, cy = (float(v) for v in p0.split()[1:8])
    images = sorted((folder / "image_0").glob("*.png"))
    height, width = cv2.imread(str(images[0]), cv2.IMREAD_GRAYSCALE).shape
    camera = CameraIntrinsics(fx=fx, fy=fy, cx=cx, cy=cy, width=width, height=height)
    rows = np.loadtxt(root / "poses" / "05.txt", ndmin=2).reshape(-1, 3, 4)
    gt = np.tile(np.eye(4), (len(rows), 1, 1))
    gt[:, :3, :] = rows
    return camera, np.loadtxt(folder / "times.txt", ndmin=1), gt, images


def own_vo(kitti_root: Path) -> OwnVo:
    """ORB (1500 per frame), knn matching with Lowe's ratio test, the essential matrix in RANSAC and its
    decomposition (OpenCV), frame to frame over KITTI 05 `FRAMES` (~20 s here; at half resolution it was twice as
    fast but failed at frame 36, a real bug of its own worse than the planted ones)."""
    camera, times, gt, images = _kitti(kitti_root)
    orb, matcher = cv2.ORB_create(nfeatures=1500), cv2.BFMatcher(cv2.NORM_HAMMING)
    steps: dict[int, OwnStep] = {}
    previous = None
    for i in range(*FRAMES):
        keypoints, descriptors = orb.detectAndCompute(cv2.imread(str(images[i]), cv2.IMREAD_GRAYSCALE), None)
        if previous is None:
            steps[i] = OwnStep(None, None, None, None, "ok", [])
            previous = (keypoints, descriptors)
            continue
        pairs = matcher.knnMatch(previous[1], descriptors, k=2)
        good = [p[0] for p in pairs if len(p) == 2 and p[0].distance < 0.8 * p[1].distance]
        prev_px = np.array([previous[0][m.queryIdx].pt for m in good], np.float32).reshape(-1, 2)
        cur_px = np.array([keypoints[m.trainIdx].pt for m in good], np.float32).reshape(-1, 2)
        tracks = Tracks(ids=np.array([m.trainIdx for m in good], np.int64) + 100_000 * i, prev=prev_px, cur=cur_px)
        previous = (keypoints, descriptors)
        if len(good) < 40:
            steps[i] = OwnStep(None, None, tracks, None, "fail", ["few_matches"])
            continue
        E, mask = cv2.findEssentialMat(prev_px, cur_px, camera.K, cv2.RANSAC, 0.999, 1.0)  # noqa: N806
        count, R, t, mask = cv2.recoverPose(E[:3], prev_px, cur_px, camera.K, mask=mask)  # noqa: N806
        inliers = mask.reshape(-1) > 0
        health: Literal["ok", "warn"] = "warn" if count < 0.5 * len(good) else "ok"
        steps[i] = OwnStep(R, t.reshape(3), tracks, inliers, health, ["low_inlier_ratio"] if health == "warn" else [])
    return OwnVo(camera, times, gt, steps)


def log_own(vo: OwnVo, path: Path, bug: Bug, with_gt: bool, detail: Literal["summary", "standard"] = "summary"
            ) -> Path:
    """The own VO's frames through `FrameLog`, step lengths from the ground truth, `bug` planted in the step of
    `BUG_FRAME` (by the pipeline: the recorded step is the bad one)."""
    pose = np.eye(4)
    with FrameLog(path, camera=vo.camera, source="kitti-05", pipeline="own-vo", detail=detail,
                  ground_truth=vo.gt if with_gt else None, properties={"bug": bug}) as log:
        for i, step in vo.steps.items():
            if step.R is not None and step.t is not None:
                length = float(np.linalg.norm(vo.gt[i, :3, 3] - vo.gt[i - 1, :3, 3]))
                T_cur_prev = np.eye(4)  # noqa: N806
                T_cur_prev[:3, :3], T_cur_prev[:3, 3] = step.R, length * step.t
                T_prev_cur = invert_pose(T_cur_prev)  # noqa: N806
                pose = pose @ (bad_step(T_prev_cur, bug) if i == BUG_FRAME else T_prev_cur)
            log.frame(i, pose=pose, time=float(vo.times[i]), tracks=step.tracks, inliers=step.inliers,
                      health=step.health, reasons=step.reasons)
    return path
