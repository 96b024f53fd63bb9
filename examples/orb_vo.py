"""A small monocular VO that is not vslam's, logging every frame through vslam's logging API (`vslam.log`).

ORB features (OpenCV), brute-force Hamming matching with cross-check, the essential matrix in RANSAC
(cv2.findEssentialMat, Nistér's five-point algorithm) and its decomposition with the cheirality check
(cv2.recoverPose). Frame-to-frame only; the step length comes from the KITTI ground truth (``--scale gt``) or is
1 (``--scale unit``). Reads the KITTI odometry layout itself (sequences/SS/{calib.txt,times.txt,image_0/},
poses/SS.txt).

    python examples/orb_vo.py /data/kitti --sequence 05 --frames 0:40 -o orb.rrd
    vslam check orb.rrd && vslam inspect orb.rrd

``--bug flip`` (the step's translation negated) or ``--bug kink`` (its rotation turned 3° further) at
``--bug-frame`` plants a bug to find: `vslam inspect` lists that frame first among its suspects, and `vslam compare`
against a clean run among its top divergences.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import cv2
import numpy as np

from vslam.log import CameraIntrinsics, FrameLog, HealthText, Tracks

MIN_MATCHES = 60  # fewer: the frame fails, its pose is held
MIN_INLIERS = 30
WARN_INLIER_RATIO = 0.5
KINK_DEG = 3.0


def planted(T_cur_prev: np.ndarray, bug: str) -> np.ndarray:  # noqa: N803
    """The step with a bug: its translation negated (flip) or its rotation turned `KINK_DEG` about y (kink)."""
    out = T_cur_prev.copy()
    if bug == "flip":
        out[:3, 3] = -out[:3, 3]
    elif bug == "kink":
        a = np.radians(KINK_DEG)
        turn = np.array([[np.cos(a), 0.0, np.sin(a)], [0.0, 1.0, 0.0], [-np.sin(a), 0.0, np.cos(a)]])
        out[:3, :3] = turn @ out[:3, :3]
    return out


def read_kitti(root: Path, sequence: str) -> tuple[CameraIntrinsics, np.ndarray, np.ndarray, list[Path]]:
    """Camera (P0 of calib.txt), times (s), ground truth (N, 4, 4) T_world_cam and the image files."""
    folder = root / "sequences" / sequence
    p0 = next(line for line in (folder / "calib.txt").read_text().splitlines() if line.startswith("P0:"))
    fx, _, cx, _, _, fy, cy = (float(v) for v in p0.split()[1:8])
    images = sorted((folder / "image_0").glob("*.png"))
    height, width = cv2.imread(str(images[0]), cv2.IMREAD_GRAYSCALE).shape
    camera = CameraIntrinsics(fx=fx, fy=fy, cx=cx, cy=cy, width=width, height=height, origin=f"{folder}/calib.txt")
    times = np.loadtxt(folder / "times.txt", ndmin=1)
    rows = np.loadtxt(root / "poses" / f"{sequence}.txt", ndmin=2).reshape(-1, 3, 4)
    gt = np.tile(np.eye(4), (len(rows), 1, 1))
    gt[:, :3, :] = rows
    return camera, times, gt, images


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("kitti_root", type=Path)
    parser.add_argument("--sequence", default="05")
    parser.add_argument("--frames", default="0:40", help="START:END of the sequence's frames")
    parser.add_argument("--scale", choices=("gt", "unit"), default="gt")
    parser.add_argument("-o", "--output", type=Path, required=True)
    parser.add_argument("--trajectory-out", type=Path, help="also write the poses here (KITTI format)")
    parser.add_argument("--bug", choices=("none", "flip", "kink"), default="none", help="plant a bug in one step")
    parser.add_argument("--bug-frame", type=int, default=57, help="the frame whose step gets the bug")
    parser.add_argument("--force", action="store_true", help="replace an existing output")
    args = parser.parse_args()
    start, end = (int(v) for v in args.frames.split(":"))
    camera, times, gt, images = read_kitti(args.kitti_root, args.sequence)
    K = camera.K  # noqa: N806
    orb = cv2.ORB_create(nfeatures=2000)
    matcher = cv2.BFMatcher(cv2.NORM_HAMMING, crossCheck=True)
    pose = np.eye(4)  # T_world_cam
    previous: tuple[list[cv2.KeyPoint], np.ndarray] | None = None
    with FrameLog(args.output, camera=camera, source=f"kitti-{args.sequence}", pipeline="orb-vo",
                  ground_truth=gt, scale="metric" if args.scale == "gt" else "none",
                  properties={"source_path": str(args.kitti_root), "bug": args.bug}, trajectory=args.trajectory_out,
                  force=args.force) as log:
        for i in range(start, min(end, len(images))):
            image = cv2.imread(str(images[i]), cv2.IMREAD_GRAYSCALE)
            t0 = time.perf_counter()
            keypoints, descriptors = orb.detectAndCompute(image, None)
            t1 = time.perf_counter()
            corners = np.array([k.pt for k in keypoints], np.float32).reshape(-1, 2)
            if previous is None or descriptors is None:
                log.frame(i, pose=pose, time=float(times[i]), image=image, corners=corners, health="ok",
                          timings_ms={"detect": 1e3 * (t1 - t0)})
                previous = (keypoints, descriptors)
                continue
            matches = matcher.match(previous[1], descriptors)
            prev_px = np.array([previous[0][m.queryIdx].pt for m in matches], np.float32).reshape(-1, 2)
            cur_px = np.array([keypoints[m.trainIdx].pt for m in matches], np.float32).reshape(-1, 2)
            ids = np.array([m.trainIdx for m in matches], np.int64) + 100_000 * i  # a match lives one frame
            t2 = time.perf_counter()
            health: HealthText = "ok"
            reasons: list[str] = []
            inliers: np.ndarray | None = None  # no inlier flags unless RANSAC ran
            if len(matches) < MIN_MATCHES:
                health, reasons = "fail", ["few_matches"]
            else:
                E, mask = cv2.findEssentialMat(prev_px, cur_px, K, cv2.RANSAC, 0.999, 1.0)  # noqa: N806
                if E is None or E.shape != (3, 3):  # none, or several solutions stacked
                    health, reasons = "fail", ["no_essential_matrix"]
                else:
                    # R, t: X_cur = R·X_prev + t (unit t); mask: RANSAC inliers in front of both cameras
                    count, R, t, mask = cv2.recoverPose(E, prev_px, cur_px, K, mask=mask)  # noqa: N806
                    inliers = mask.reshape(-1) > 0
                    if count < MIN_INLIERS:
                        health, reasons = "fail", ["few_inliers"]
                    else:
                        step = float(np.linalg.norm(gt[i, :3, 3] - gt[i - 1, :3, 3])) if args.scale == "gt" else 1.0
                        T_cur_prev = np.eye(4)  # noqa: N806
                        T_cur_prev[:3, :3], T_cur_prev[:3, 3] = R, step * t.reshape(3)
                        pose = pose @ np.linalg.inv(planted(T_cur_prev, args.bug) if i == args.bug_frame
                                                    else T_cur_prev)
                        if count / len(matches) < WARN_INLIER_RATIO:
                            health, reasons = "warn", ["low_inlier_ratio"]
            t3 = time.perf_counter()
            log.frame(i, pose=pose, time=float(times[i]), image=image, corners=corners,
                      tracks=Tracks(ids=ids, prev=prev_px, cur=cur_px), inliers=inliers, health=health, reasons=reasons,
                      scalars={"matches": len(matches), "keypoints": len(keypoints)},
                      timings_ms={"detect": 1e3 * (t1 - t0), "track": 1e3 * (t2 - t1), "essential": 1e3 * (t3 - t2)})
            previous = (keypoints, descriptors)
    print(f"{args.output}: {log.frames} frames of kitti-{args.sequence} {start}:{end} (orb-vo)")


if __name__ == "__main__":
    main()
