"""One development matrix: every kind of data the engine must hold on, both backends, with and without a scale source.

    python -m benchmarks.matrix [--quick] [--groups kitti,tum,street,loop,walk,lens,handheld,small] [--seeds 0,1]
        [--jobs 2] [--csv matrix.csv] [--compare before.csv] [--kitti ../shared/data/kitti] [--tum ../shared/data/tum]
    python -m benchmarks.matrix --table matrix.csv [--compare before.csv]     # print a saved CSV (no runs)

Families (`--groups`):
  kitti     KITTI 00 and 05, windows 0:150, 150:300 and 0:300 (two starts and both) at frame steps 1, 2 and 3
            (``--frames a:b:step``: a 10, 5 and 3.3 Hz camera); scales gt, height and none; one group per step
  tum       the two TUM RGB-D hand-held sequences (../shared/data/tum, 200 frames each); gt and none
  street, loop, walk   the synthetic street (300 frames), its closed loop (660) and the hand-held walk (0:200)
  lens      KITTI 00 0:150 and 05 0:150 re-imaged through a strong radial–tangential lens (benchmarks/gaps.py
            --lens, tests/ros_logs.py), read as an image folder with its calibration YAML; gt and none
  handheld  KITTI 05 0:150 re-imaged through a swinging virtual camera (benchmarks/handheld.py); gt and none
  small     KITTI 00 0:300 and 05 0:300 at half size (620x188 and 613x185 px: a camera with half the focal length
            in pixels), read as an image folder with its calibration YAML; gt, height and none

Every (family case, backend vo|map, scale, RANSAC seed) is one run of `run_odometry` with the default config but
the backend, scale source and `pose.seed` (and threads = 1: pool workers are daemonic, and trajectories do not
depend on threads; benchmarks/accuracy.py). Runs go through a pool of `--jobs` processes, seed by seed and the
shortest first (an interrupted matrix has as many groups as it could); each row is appended to the CSV as it finishes
(`--resume` keeps the rows of an interrupted matrix and runs the rest), and the table is printed in a fixed
order, so the output is deterministic (the CSV's ``seconds`` column aside). A run that fails (a source that does
not open, an engine error) is a row with its error, not a crash.

`--quick` (for iterating): KITTI 00 0:150, 05 0:150:2 and 00 0:150:3 with gt and none, TUM fr1_xyz, the synthetic
street 0:100 and walk 0:120; the loop, lens, hand-held and half-size families only when `--groups` names them (then
their first case).

Per group (family, backend, scale): a mean row and the worst run (largest ATE after Sim(3)), with ATE after
Sim(3) and without alignment, KITTI t_err (after Sim(3) with --scale none), the final rotation error, frames
held, where the map placed each frame (% by PnP against the map / two-view / relocalised, coasted or lost) and
the noise (std over seeds of the group's mean; benchmarks/matrix_table.py). `--compare before.csv` prints per
group the change against a saved CSV and flags a group worse beyond its noise. How to judge a change:
docs/matrix.md.
"""

from __future__ import annotations

import argparse
import dataclasses
import math
import multiprocessing
import os
import sys
import tempfile
import time
import traceback
from pathlib import Path

import numpy as np

from benchmarks.accuracy import benchmark_config
from benchmarks.matrix_table import FIELDS, Row, compare, read_csv, table, write_csv
from vslam_core.geometry import invert_pose, rotation_angle
from vslam_core.pipeline import run_odometry
from vslam_core.results import TrackingMode
from vslam_core.sources.base import CameraIntrinsics, FrameRange, FrameSource
from vslam_core.trajectory.metrics import ate, kitti_errors, sim3_aligned

FAMILIES = ("kitti", "tum", "street", "loop", "walk", "lens", "handheld", "small")
#: --quick without --groups: the families that run in minutes (their cases trimmed in `make_jobs`)
QUICK_FAMILIES = ("kitti", "tum", "street", "walk")
KITTI_WINDOWS = ("0:150", "150:300", "0:300")  # two starts, and both together: drift over 300 frames
STEPS = (1, 2, 3)
BACKENDS = ("vo", "map")
SCALES = ("gt", "height", "none")
TUM_SEQUENCES = ("rgbd_dataset_freiburg1_xyz", "rgbd_dataset_freiburg1_desk")
LENS_CASES = (("00", "0:150"), ("05", "0:150"))
HANDHELD_CASE = ("05", "0:150")
SMALL_CASES = (("00", "0:300"), ("05", "0:300"))
KITTI_CAMERA_HEIGHT_M = 1.65  # the re-imaged KITTI folders' --camera-height (KittiSource's own)
MODES = {"map": TrackingMode.MAP, "two_view": TrackingMode.TWO_VIEW, "relocalised": TrackingMode.RELOCALISED,
         "coasted": TrackingMode.COASTED, "init": TrackingMode.INIT, "lost": TrackingMode.LOST}


@dataclasses.dataclass(frozen=True)
class Job:
    family: str  # the table's group name, e.g. "KITTI step 2"
    case: str  # which data, e.g. "00 0:300:2"
    kind: str  # kitti, tum, synthetic, folder (lens, half size), clip (hand-held)
    path: str  # KITTI root, TUM sequence folder, synthetic route, or the prepared folder
    frames: str  # FrameRange text ("" for all)
    sequence: str
    backend: str
    scale: str
    seed: int
    cost: float  # frames × the backend's relative cost: the pool starts the longest first
    camera_height_m: float = 0.0  # --camera-height (0: the source's own): for KITTI frames read as a folder


def open_job_source(job: Job) -> FrameSource:
    """The job's frames (with ground truth)."""
    frames = FrameRange.parse(job.frames or None)
    if job.kind == "kitti":
        from vslam_core.sources.kitti import KittiSource

        return KittiSource(job.path, sequence=job.sequence, frames=frames)
    if job.kind == "synthetic":
        from vslam_core.sources.synthetic import SyntheticStreet

        return SyntheticStreet(route=job.path, frames=frames)  # type: ignore[arg-type]
    if job.kind == "folder":  # KITTI re-imaged (a lens, half size): the folder and its calibration YAML beside it
        from vslam_core.sources.folder import ImageFolderSource

        return ImageFolderSource(job.path, calib=f"{job.path}.yaml", ground_truth=f"{job.path}/gt.txt", frames=frames)
    from vslam_core.sources.open import open_source

    if job.kind == "clip":  # benchmarks/handheld.py's folder
        return open_source(str(Path(job.path) / "image_0"), ground_truth=Path(job.path) / "gt.txt", frames=frames)
    return open_source(job.path, frames=frames)  # TUM RGB-D: its own ground truth, matched by time


def final_rotation_deg(gt: np.ndarray, poses: np.ndarray) -> float:
    """Degrees between the estimated and the true rotation of the last frame relative to the first."""
    true = invert_pose(gt[0]) @ gt[-1]
    estimate = invert_pose(poses[0]) @ poses[-1]
    return math.degrees(rotation_angle(true[:3, :3].T @ estimate[:3, :3]))


def run_job(job: Job) -> Row:
    """One run as a CSV row; any failure becomes the row's ``error`` (one line) instead of stopping the matrix."""
    row: Row = {"family": job.family, "case": job.case, "backend": job.backend, "scale": job.scale, "seed": job.seed,
                "frames": 0, "error": ""}
    start = time.perf_counter()
    try:
        source = open_job_source(job)
        gt = source.ground_truth
        if gt is None:
            raise ValueError("no ground truth")
        config = benchmark_config(None, job.backend, job.scale, job.seed)  # type: ignore[arg-type]
        if job.camera_height_m:
            config = dataclasses.replace(config, height=dataclasses.replace(config.height,
                                                                            camera_height_m=job.camera_height_m))
        run = run_odometry(source, config)
        poses = run.pose_array()
        gt = gt[: len(poses)]
        scored = sim3_aligned(gt, poses) if job.scale == "none" else poses
        row.update(frames=len(poses), ate_sim3=ate(gt, poses, "sim3"),
                   ate=ate(gt, poses, "none") if job.scale != "none" else math.nan,
                   t_err=kitti_errors(gt, scored)[0], rotation_deg=final_rotation_deg(gt, poses),
                   held=run.held, coasted=run.coasted)
        if job.backend == "map":  # where the map placed each frame (counted from the per-frame results)
            row.update({f"placed_{name}": run.modes.get(mode, 0) for name, mode in MODES.items()})
    except Exception as exc:  # noqa: BLE001 - the matrix records a failing run in its row
        text = " ".join(str(exc).split()) or type(exc).__name__
        row["error"] = f"{type(exc).__name__}: {text}"[:300]
        if os.environ.get("VSLAM_MATRIX_TRACEBACK"):
            traceback.print_exc()
    row["seconds"] = round(time.perf_counter() - start, 1)
    return row


def make_jobs(families: list[str], seeds: list[int], kitti: str, tum: str, folders: dict[str, str],
              quick: bool, backends: tuple[str, ...] = BACKENDS, scales_kept: tuple[str, ...] = SCALES) -> list[Job]:
    """Every run of the chosen families (`folders`: the prepared lens folders by sequence, and ``handheld``),
    of the chosen backends and scale sources only."""
    specs: list[tuple[str, str, str, str, str, str, tuple[str, ...], int]] = []  # + scales, frame count
    if "kitti" in families:
        cases = ([("00", "0:150", 1), ("05", "0:150", 2), ("00", "0:150", 3)] if quick else
                 [(s, w, step) for step in STEPS for s in ("00", "05") for w in KITTI_WINDOWS])
        for sequence, window, step in cases:
            a, b = (int(v) for v in window.split(":"))
            frames = f"{window}:{step}" if step > 1 else window
            scales = ("gt", "none") if quick else ("gt", "height", "none")
            specs.append((f"KITTI step {step}", f"{sequence} {frames}", "kitti", kitti, frames, sequence, scales,
                          len(range(a, b, step))))
    if "tum" in families:
        for name in TUM_SEQUENCES[:1] if quick else TUM_SEQUENCES:
            specs.append(("TUM hand-held", name.removeprefix("rgbd_dataset_"), "tum", str(Path(tum) / name), "", "",
                          ("gt", "none"), 200))
    synthetic = {"street": ("synthetic street", "0:100" if quick else "", 300), "loop": ("synthetic loop", "", 660),
                 "walk": ("synthetic walk", "0:120" if quick else "0:200", 450)}
    for route, (family, frames, count) in synthetic.items():
        if route in families:
            length = len(FrameRange.parse(frames or None).indices(count))
            specs.append((family, f"{route} {frames or 'all'}", "synthetic", route, frames, "", ("gt", "none"), length))
    if "lens" in families:
        for sequence, window in LENS_CASES[:1] if quick else LENS_CASES:
            a, b = (int(v) for v in window.split(":"))
            specs.append(("KITTI through a lens", f"{sequence} {window}", "folder", folders[f"lens-{sequence}"],
                          f"0:{b - a}", sequence, ("gt", "none"), b - a))
    if "handheld" in families:
        sequence, window = HANDHELD_CASE
        a, b = (int(v) for v in window.split(":"))
        specs.append(("hand-held clip", f"{sequence} {window} swinging", "clip", folders["handheld"], "", sequence,
                      ("gt", "none"), b - a))
    if "small" in families:
        for sequence, window in SMALL_CASES[:1] if quick else SMALL_CASES:
            a, b = (int(v) for v in window.split(":"))
            specs.append(("KITTI at half size", f"{sequence} {window}", "folder", folders[f"small-{sequence}"],
                          "", sequence, ("gt", "height", "none"), b - a))
    jobs = [Job(family, case, kind, path, frames, sequence, backend, scale, seed,
                count * (3.5 if backend == "map" else 1.0), KITTI_CAMERA_HEIGHT_M if kind == "folder" else 0.0)
            for family, case, kind, path, frames, sequence, scales, count in specs
            for backend in backends for scale in scales if scale in scales_kept for seed in seeds]
    return jobs


def prepare_folders(families: list[str], kitti: str, quick: bool, scratch: Path) -> dict[str, str]:
    """The re-imaged frames the lens, hand-held and half-size families run on (written once, before the pool
    starts)."""
    folders: dict[str, str] = {}
    if "lens" in families:
        from benchmarks.gaps import write_lens_folder

        for sequence, window in LENS_CASES[:1] if quick else LENS_CASES:
            folders[f"lens-{sequence}"] = write_lens_folder(kitti, sequence, window, scratch)
    if "handheld" in families:
        from benchmarks.handheld import write_clip

        sequence, window = HANDHELD_CASE
        folders["handheld"] = str(write_clip(Path(kitti), sequence, FrameRange.parse(window), 1.0,
                                             scratch / "handheld"))
    if "small" in families:
        for sequence, window in SMALL_CASES[:1] if quick else SMALL_CASES:
            folders[f"small-{sequence}"] = str(write_half_size_folder(Path(kitti), sequence, window, scratch))
    return folders


@dataclasses.dataclass(frozen=True)
class HalfSize:
    """KITTI frames resized to `camera`'s size (``cv2.INTER_AREA``): a `tests.ros_logs.Reimaging`."""

    camera: CameraIntrinsics

    def __call__(self, kitti_image: np.ndarray) -> np.ndarray:
        import cv2

        return cv2.resize(kitti_image, (self.camera.width, self.camera.height), interpolation=cv2.INTER_AREA)


def write_half_size_folder(kitti: Path, sequence: str, window: str, scratch: Path) -> Path:
    """The window's KITTI frames at half size (each side rounded down) as an image folder with ``times.txt``,
    ``gt.txt`` and the camera resized to them as ``FOLDER.yaml`` beside it (`tests.ros_logs.write_lens_folder`;
    pixel centres at integers: ``c' = (c + 0.5) · s − 0.5`` per axis, as `scale_calibration`, which needs one factor
    for both axes and 00's 1241 px do not halve)."""
    from tests.ros_logs import kitti_clip, write_lens_folder

    a, b = (int(v) for v in window.split(":"))
    clip = kitti_clip(kitti, sequence, range(a, b))
    camera = clip.camera
    size = (camera.width // 2, camera.height // 2)
    sx, sy = size[0] / camera.width, size[1] / camera.height
    small = CameraIntrinsics(camera.fx * sx, camera.fy * sy, (camera.cx + 0.5) * sx - 0.5, (camera.cy + 0.5) * sy - 0.5,
                             size[0], size[1], origin=f"KITTI {sequence} at half size")
    folder = scratch / f"small-{sequence}"
    write_lens_folder(clip, HalfSize(small), folder)
    return folder


def _split(text: str, allowed: tuple[str, ...], name: str, parser: argparse.ArgumentParser) -> list[str]:
    items = [part.strip() for part in text.split(",") if part.strip()]
    if not items or any(item not in allowed for item in items):
        parser.error(f"{name} {text!r}: a comma-separated list of {', '.join(allowed)}")
    return items


def job_key(row: Row | Job) -> tuple[str, str, str, str, str]:
    """What identifies a run (a CSV row or a job)."""
    if isinstance(row, Job):
        return row.family, row.case, row.backend, row.scale, str(row.seed)
    return str(row["family"]), str(row["case"]), str(row["backend"]), str(row["scale"]), str(row["seed"])


def run_matrix(jobs: list[Job], processes: int, csv_path: Path | None, kept: list[Row] | None = None) -> list[Row]:
    """Every job's row, in the jobs' order; with `csv_path`, each row is also written there as it finishes (the
    CSV of an interrupted matrix keeps the rows done). `kept`: rows of an earlier, interrupted matrix (its CSV,
    `--resume`): their jobs are not run again."""
    earlier = {job_key(row): row for row in kept or [] if not row.get("error")}
    done: dict[int, Row] = {i: earlier[job_key(job)] for i, job in enumerate(jobs) if job_key(job) in earlier}
    # seed by seed, the shortest runs first: an interrupted matrix (a loaded machine) has as many groups as it can
    order = sorted((i for i in range(len(jobs)) if i not in done), key=lambda i: (jobs[i].seed, jobs[i].cost))
    if not order:
        return [done[i] for i in range(len(jobs))]
    # spawn: the lens and hand-held folders were written with OpenCV in this process
    with multiprocessing.get_context("spawn").Pool(processes) as pool:
        for position, row in zip(order, pool.imap(run_job, [jobs[i] for i in order], chunksize=1), strict=True):
            done[position] = row
            if csv_path is not None:
                write_csv(csv_path, [done[i] for i in sorted(done)])
            outcome = f"FAILED {row['error']}" if row["error"] else f"ATE Sim(3) {row['ate_sim3']:.3f} m"
            print(f"[{len(done)}/{len(jobs)}] {row['family']} {row['case']} {row['backend']} {row['scale']} "
                  f"seed {row['seed']}: {outcome} ({row['seconds']} s)", file=sys.stderr, flush=True)
    return [done[i] for i in range(len(jobs))]


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--quick", action="store_true", help="a small subset for iterating (minutes on 2 cores)")
    parser.add_argument("--groups", default=None, help="families to run: " + ", ".join(FAMILIES) + " (default: all; "
                        "with --quick " + ", ".join(QUICK_FAMILIES) + ")")
    parser.add_argument("--seeds", default="0,1", help="RANSAC seeds (pose.seed); two or more measure the noise")
    parser.add_argument("--backends", default=",".join(BACKENDS), help="backends to run (default: vo,map)")
    parser.add_argument("--scales", default=",".join(SCALES), help="scale sources to run (default: gt,height,none; "
                        "a family runs those of its own it names)")
    parser.add_argument("--jobs", type=int, default=2)
    parser.add_argument("--csv", type=Path, default=None, help="write one row per run here (as they finish)")
    parser.add_argument("--compare", type=Path, default=None, help="a saved matrix CSV: per-group deltas")
    parser.add_argument("--table", type=Path, default=None, help="print this saved CSV's table instead of running")
    parser.add_argument("--resume", action="store_true", help="keep the rows --csv already holds (an interrupted "
                        "matrix) and run only the others")
    parser.add_argument("--kitti", default="../shared/data/kitti")
    parser.add_argument("--tum", default="../shared/data/tum")
    args = parser.parse_args(argv)
    try:
        before = read_csv(args.compare) if args.compare is not None else None
        rows = read_csv(args.table) if args.table is not None else None
    except (OSError, ValueError) as exc:
        parser.error(str(exc))
    if rows is None:
        chosen = args.groups or ",".join(QUICK_FAMILIES if args.quick else FAMILIES)
        families = _split(chosen, FAMILIES, "--groups", parser)
        backends = tuple(_split(args.backends, BACKENDS, "--backends", parser))
        scales = tuple(_split(args.scales, SCALES, "--scales", parser))
        try:
            seeds = [int(s) for s in args.seeds.split(",") if s.strip()]
        except ValueError:
            parser.error(f"--seeds {args.seeds!r}: comma-separated integers")
        if args.jobs < 1 or not seeds:
            parser.error("--jobs must be ≥ 1 and --seeds name at least one seed")
        kept = read_csv(args.csv) if args.resume and args.csv is not None and args.csv.exists() else None
        start = time.perf_counter()
        with tempfile.TemporaryDirectory(prefix="vslam-matrix-") as scratch:
            # the synthetic frames are rendered once and shared by every run of a route (its backends and seeds)
            os.environ.setdefault("VSLAM_SYNTHETIC_CACHE", str(Path(scratch) / "synthetic"))
            folders = prepare_folders(families, args.kitti, args.quick, Path(scratch))
            jobs = make_jobs(families, seeds, args.kitti, args.tum, folders, args.quick, backends, scales)
            rows = run_matrix(jobs, args.jobs, args.csv, kept)
        minutes = (time.perf_counter() - start) / 60
        print(f"{'quick ' if args.quick else ''}matrix: {len(rows)} runs of {', '.join(families)}, seeds "
              f"{args.seeds}, {args.jobs} jobs: {minutes:.1f} min wall (speed varies with the machine's load)")
    print(table(rows))
    if before is not None:
        text, flagged = compare(before, rows)
        print("\n" + text)
        if flagged:
            print("\n".join(f"  worse: {line}" for line in flagged))


if __name__ == "__main__":
    main()


__all__ = ["FIELDS", "Job", "make_jobs", "run_job", "main"]
