"""`vslam check` is a contract (issue 54, item 1): a recording it accepts works with every command that reads
recordings (`inspect`, `inspect --json`, `compare`, `crop`, `eval --trajectory x.rrd`, and `snapshot` for two
of them); one it rejects gets one line from them (exit 2), never a traceback.

A property test writes schema recordings with random subsets of the optional entities, both with the plain Rerun
SDK (following docs/recording-schema.md only, as a C++ pipeline would) and with `vslam.log.FrameLog`, frames
that need not start at 0 nor be contiguous, and runs every command on each through the CLI's entry point
(in this process: `cli_helpers.vslam`, which lets any exception through). Broken variants (a schema violation
each) must be rejected by `check` and cost the other commands one line at most. The counts of recordings and
commands are printed (``-s``) and checked."""

from __future__ import annotations

import json
import math
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pyarrow as pa
import pytest
import rerun as rr
from cli_helpers import need_vulkan, vslam
from hypothesis import HealthCheck, Phase, given, settings
from hypothesis import strategies as st

from vslam.log import CameraIntrinsics, FrameLog
from vslam_core.trajectory.io import write_kitti_poses

#: Per-frame series of the schema (docs/recording-schema.md, "Entities").
SERIES = ("/metrics/health/status", "/metrics/tracks/alive", "/metrics/tracks/new_corners",
          "/metrics/tracks/fb_rejected", "/metrics/tracks/road_points", "/metrics/ransac/inliers",
          "/metrics/ransac/chirality_margin", "/metrics/ratio/inlier_ratio", "/metrics/motion/rotation_deg",
          "/metrics/motion/scale", "/metrics/error/position_m", "/metrics/angle_error/heading_deg",
          "/metrics/angle_error/translation_direction_deg", "/metrics/drift/rotation_deg",
          "/metrics/drift/translation_m", "/metrics/drift/translation_pct", "/metrics/drift/scale_ratio",
          "/metrics/timing_ms/decode", "/metrics/timing_ms/track", "/metrics/timing_ms/essential",
          "/metrics/timing_ms/detect", "/metrics/custom/matches")
#: Optional entities other than the series.
ENTITIES = ("time", "world", "image", "corners", "flow", "estimate", "ground_truth", "gt_first_segment",
            "estimate_sim3", "drift", "gt_links", "health", "health_quiet", "events", "report")
#: One schema violation each: `check` must reject the recording, the other commands end in one line at most.
BREAKS = ("numeric_health", "unknown_health", "no_schema_version", "no_frame_count", "frame_component",
          "camera_without_rotation", "misnamed_camera", "frame_duration")
REPORT = ("# my-vo\n\n| sequence | frames | t_err (%) | r_err (°/100m) | ATE SE3 (m) | ATE Sim3 (m) |\n"
          "|---|---|---|---|---|---|\n| kitti-05 | 9 | n/a | n/a | 0.123 | 0.100 |\n")
CAMERA = CameraIntrinsics(fx=70.0, fy=70.0, cx=32.0, cy=24.0, width=64, height=48)
ROTATIONS = ("mat3x3", "quaternion", "axis_angle")


@dataclass
class Tally:
    """What the property tests did, printed at the end and checked."""

    recordings: dict[str, int] = field(default_factory=lambda: {"sdk": 0, "framelog": 0, "broken": 0})
    commands: int = 0


TALLY = Tally()


def _path(frames: list[int], seed: int) -> np.ndarray:
    """(N, 4, 4) T_world_cam of a car-like path: forward steps with a little yaw, first pose the identity."""
    rng = np.random.default_rng(seed)
    poses = [np.eye(4)]
    for _ in frames[1:]:
        yaw = rng.normal(0.0, 0.02)
        step = np.eye(4)
        step[:3, :3] = np.array([[math.cos(yaw), 0, math.sin(yaw)], [0, 1, 0], [-math.sin(yaw), 0, math.cos(yaw)]])
        step[:3, 3] = [rng.normal(0, 0.05), rng.normal(0, 0.01), 1.0 + rng.normal(0, 0.1)]
        poses.append(poses[-1] @ step)
    return np.array(poses)


def _rotation(pose: np.ndarray, kind: str) -> dict[str, object]:
    if kind == "mat3x3":
        return {"mat3x3": pose[:3, :3]}
    from vslam_core.trajectory.io import quaternion_from_rotation

    q = quaternion_from_rotation(pose[:3, :3])
    if kind == "quaternion":
        return {"quaternion": rr.Quaternion(xyzw=q)}
    angle = 2.0 * math.atan2(float(np.linalg.norm(q[:3])), float(q[3]))
    axis = q[:3] / np.linalg.norm(q[:3]) if np.linalg.norm(q[:3]) > 1e-12 else np.array([0.0, 1.0, 0.0])
    return {"rotation_axis_angle": rr.RotationAxisAngle(axis=axis, radians=angle)}


def write_sdk(path: Path, frames: list[int], options: set[str], series: set[str], rotation: str, seed: int,
              broken: str | None = None) -> Path:
    """A recording written with `rr.RecordingStream` alone, from docs/recording-schema.md: the required camera
    poses and run properties, and the optional entities and series in `options` and `series` (a series on every
    other frame when its name sorts odd: sparse series are allowed). `broken`: one schema violation."""
    poses = _path(frames, seed)
    truth = _path(frames, seed + 1)
    rec = rr.RecordingStream("my-cpp-vo")
    rec.save(path)
    properties = {"schema_version": "1", "name": f"my-cpp-vo kitti-05 frames {frames[0]}:{frames[-1] + 1}",
                  "source": "kitti-05", "frames": f"{frames[0]}..{frames[-1]} ({len(frames)} frames)",
                  "frame_count": str(len(frames))}
    if broken == "no_schema_version":
        del properties["schema_version"]
    if broken == "no_frame_count":
        del properties["frame_count"]
    rec.send_property("run", rr.AnyValues(**properties))  # type: ignore[arg-type]
    if "world" in options:
        rec.log("/world", rr.ViewCoordinates.RDF, static=True)
    if "image" in options:
        rec.log("/world/camera/image", rr.Pinhole(focal_length=70.0, width=64, height=48), static=True)
    for k, (frame, pose) in enumerate(zip(frames, poses, strict=True)):
        if broken == "frame_duration":
            rec.set_time("frame", duration=float(frame))
        else:
            rec.set_time("frame", sequence=frame)
        if "time" in options:
            rec.set_time("time", duration=0.1 * frame)
        rotation_args = {} if broken == "camera_without_rotation" else _rotation(pose, rotation)
        camera = "/world/cam" if broken == "misnamed_camera" else "/world/camera"
        rec.log(camera, rr.Transform3D(translation=pose[:3, 3], **rotation_args))  # type: ignore[arg-type]
        before = poses[max(k - 1, 0)]
        if "image" in options:
            rec.log("/world/camera/image", rr.Image(np.full((48, 64), 40 + k, np.uint8)))
        if "corners" in options:
            rec.log("/world/camera/image/corners", rr.Points2D([[10.0, 10.0], [20.0, 30.0 + k]]))
        if "flow" in options:
            rec.log("/world/camera/image/flow", rr.Arrows2D(origins=[[10.0, 10.0]], vectors=[[1.0, 0.5]],
                                                            class_ids=[5]))
        if "estimate" in options:
            rec.log("/world/trajectory/estimate", rr.LineStrips3D([[before[:3, 3], pose[:3, 3]]]))
        if "ground_truth" in options and (k > 0 or "gt_first_segment" in options):
            rec.log("/world/trajectory/ground_truth",
                    rr.LineStrips3D([[truth[max(k - 1, 0)][:3, 3], truth[k][:3, 3]]]))
        if "drift" in options and k > 0:
            rec.log("/world/trajectory/drift", rr.LineStrips3D([[before[:3, 3], pose[:3, 3]]], colors=[[255, 0, 0]]),
                    rr.AnyValues(frame_index=[frame], translation_pct=[1.5], rotation_deg=[0.1]))
        if "health_quiet" in options and "health" not in options:  # every frame ok, no reason: the SDK drops
            rec.log("/health", rr.AnyValues(status="ok", reasons=""))  # reasons="" (no such component at all)
        if "health" in options:
            status: object = ["ok", "warn", "fail"][k % 3]
            if broken == "numeric_health":  # an Arrow array: the SDK's type cache (per process, per
                status = pa.array([k % 3], pa.int64())  # component name) would refuse an int after a string
            elif broken == "unknown_health" and k == 1:
                status = "broken"
            rec.log("/health", rr.AnyValues(status=status, reasons="few_matches" if k % 3 else ""))
        if "events" in options and k % 2 == 0:
            rec.log("/events", rr.TextLog(f"frame {frame}", level="INFO"))
        for name in sorted(series):
            if SERIES.index(name) % 2 == 1 and k % 2 == 1:
                continue  # a sparse series: not every frame has a value
            value = float(np.linalg.norm(pose[:3, 3] - truth[k][:3, 3])) if name.endswith("position_m") else 1.0 + k
            rec.log(name, rr.Scalars(value))
    if "estimate_sim3" in options:
        rec.log("/world/trajectory/estimate_sim3", rr.LineStrips3D([poses[:, :3, 3]]), static=True)
    if "gt_links" in options or broken == "frame_component":
        hover = "frame" if broken == "frame_component" else "frame_index"
        rec.log("/world/trajectory/gt_links", rr.LineStrips3D([np.zeros((2, 3))]),
                rr.AnyValues(**{hover: [frames[0]]}), static=True)  # type: ignore[arg-type]
    if "report" in options:
        rec.log("/report", rr.TextDocument(REPORT, media_type="text/markdown"), static=True)
    rec.flush()
    rec.disconnect()
    return path


def write_framelog(path: Path, frames: list[int], options: set[str], seed: int) -> Path:
    """The same with `vslam.log.FrameLog`, each optional argument given or not."""
    poses, truth = _path(frames, seed), _path(frames, seed + 1)
    rng = np.random.default_rng(seed)
    detail = "standard" if "image" in options or "corners" in options or "tracks" in options else "summary"
    with FrameLog(path, camera=CAMERA, source="kitti-05", pipeline="my-vo", detail=detail,  # type: ignore[arg-type]
                  scale="none" if "scale_none" in options else "metric") as log:
        for k, (frame, pose) in enumerate(zip(frames, poses, strict=True)):
            extra: dict[str, object] = {}
            if "time" in options:
                extra["time"] = 0.1 * frame
            if "image" in options:
                extra["image"] = np.full((48, 64), 40 + k, np.uint8)
            if "corners" in options:
                extra["corners"] = rng.uniform(0, 40, (5, 2))
            if "tracks" in options:
                ids = np.arange(k, k + 6)
                extra["tracks"] = (ids, rng.uniform(0, 40, (6, 2)), rng.uniform(0, 40, (6, 2)))
                if "inliers" in options:
                    extra["inliers"] = np.arange(6) % 3 != 0
            if "health" in options:
                extra["health"] = ["ok", "warn", "fail"][k % 3]
                extra["reasons"] = ["few_matches"] if k % 3 else []
            if "scalars" in options:
                extra["scalars"] = {"matches": 100.0 + k}
            if "timings" in options:
                extra["timings_ms"] = {"track": 2.0, "essential": 1.0}
            if "gt" in options:
                extra["gt"] = truth[k]
            log.frame(frame, pose=pose, **extra)  # type: ignore[arg-type]
    return path


def _frames(draw: st.DrawFn) -> list[int]:
    start = draw(st.sampled_from([0, 3, 50]))
    count = draw(st.integers(min_value=4, max_value=9))
    step = draw(st.sampled_from([1, 1, 2]))
    frames = list(range(start, start + count * step, step))
    if draw(st.booleans()):  # a dropped frame: indices need not be evenly spaced
        del frames[len(frames) // 2]
    return frames


@st.composite
def sdk_recordings(draw: st.DrawFn) -> tuple[list[int], set[str], set[str], str]:
    return (_frames(draw), draw(st.sets(st.sampled_from(ENTITIES))), draw(st.sets(st.sampled_from(SERIES))),
            draw(st.sampled_from(ROTATIONS)))


@st.composite
def framelog_recordings(draw: st.DrawFn) -> tuple[list[int], set[str]]:
    options = ("time", "image", "corners", "tracks", "inliers", "health", "scalars", "timings", "gt", "scale_none")
    return _frames(draw), draw(st.sets(st.sampled_from(options)))


@pytest.fixture(scope="module", autouse=True)
def tally() -> Iterator[Tally]:
    """Counts what the property tests generated and ran; printed (``-s``) and checked when the module ends."""
    yield TALLY
    print(f"\ncontract: {sum(TALLY.recordings.values())} recordings {TALLY.recordings}, {TALLY.commands} commands")
    assert TALLY.commands >= 6 * sum(TALLY.recordings.values())  # check + 5 commands each, at least


@pytest.fixture(scope="module")
def ground_truth(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A KITTI poses file with a row for every frame the recordings may hold (row i = frame i)."""
    path = tmp_path_factory.mktemp("gt") / "gt.txt"
    write_kitti_poses(path, _path(list(range(80)), 7))
    return path


@pytest.fixture(scope="module")
def baseline(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The other run of every `compare`: the minimal conforming recording of frames 0..19."""
    frames = list(range(20))
    return write_sdk(tmp_path_factory.mktemp("baseline") / "baseline.rrd", frames, set(), set(), "mat3x3", 1)


def _one_line(result: object, command: str) -> None:
    code, stderr = result.returncode, result.stderr  # type: ignore[attr-defined]
    assert code == 2, f"{command}: exit {code}: {stderr}"
    assert len(stderr.strip().splitlines()) == 1 and stderr.startswith("error: "), f"{command}: {stderr!r}"


def every_command(path: Path, frames: list[int], folder: Path, ground_truth: Path, baseline: Path,
                  conforms: bool) -> None:
    """`check`, then `inspect`, `inspect --json`, `compare`, `crop` (and `check` of the crop), `eval --trajectory`.
    Accepted: each exits 0 with its output; rejected: each exits 0 or prints one line and exits 2."""
    checked = vslam("check", path)
    assert (checked.returncode == 0) == conforms, checked.stdout
    commands = {
        "inspect": ("inspect", path),
        "inspect --json": ("inspect", path, "--json"),
        "compare": ("compare", baseline, path, "-o", folder / "compare.rrd", "--force", "--json"),
        "crop": ("crop", path, "--frames", f"{frames[1]}:", "-o", folder / "crop.rrd", "--force"),
        "eval": ("eval", "--trajectory", path, "--gt", ground_truth, "--json"),
    }
    TALLY.commands += 1
    for name, args in commands.items():
        result = vslam(*args)
        TALLY.commands += 1
        if not conforms:
            if result.returncode != 0:
                _one_line(result, name)
            continue
        assert result.returncode == 0, f"{name} of an accepted recording: {result.stderr}"
        if name == "inspect --json":
            report = json.loads(result.stdout)
            assert report["frames"]["count"] >= 3
        if name == "compare":
            assert json.loads(result.stdout)["runs"][1]["frames"] >= 3
        if name == "crop":
            again = vslam("check", folder / "crop.rrd")  # what crop keeps still conforms
            TALLY.commands += 1
            assert again.returncode == 0, again.stdout
        if name == "eval":
            matching = json.loads(result.stdout)["matching"]
            assert matching["method"] == "frame" and matching["text"].startswith("matched by frame (its recording")


#: No shrinking: each example costs ~1 s of commands; a failure prints its example as generated.
SETTINGS = settings(max_examples=6, deadline=None, derandomize=True, phases=[Phase.explicit, Phase.generate],
                    suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow])


@SETTINGS
@given(recording=sdk_recordings(), seed=st.integers(0, 1000))
def test_plain_sdk_recordings_check_accepts_work_with_every_command(
        recording: tuple[list[int], set[str], set[str], str], seed: int, tmp_path: Path, ground_truth: Path,
        baseline: Path) -> None:
    frames, options, series, rotation = recording
    folder = tmp_path / f"sdk-{TALLY.recordings['sdk']}"
    folder.mkdir()
    path = write_sdk(folder / "run.rrd", frames, options, series, rotation, seed)
    TALLY.recordings["sdk"] += 1
    every_command(path, frames, folder, ground_truth, baseline, conforms=True)


@settings(SETTINGS, max_examples=4)
@given(recording=framelog_recordings(), seed=st.integers(0, 1000))
def test_framelog_recordings_work_with_every_command(recording: tuple[list[int], set[str]], seed: int,
                                                     tmp_path: Path, ground_truth: Path, baseline: Path) -> None:
    frames, options = recording
    folder = tmp_path / f"log-{TALLY.recordings['framelog']}"
    folder.mkdir()
    path = write_framelog(folder / "run.rrd", frames, options, seed)
    TALLY.recordings["framelog"] += 1
    every_command(path, frames, folder, ground_truth, baseline, conforms=True)


@pytest.mark.parametrize("broken", BREAKS)
@settings(SETTINGS, max_examples=1)
@given(recording=sdk_recordings(), seed=st.integers(0, 1000))
def test_recordings_check_rejects_cost_one_line_at_most(
        broken: str, recording: tuple[list[int], set[str], set[str], str], seed: int, tmp_path: Path,
        ground_truth: Path, baseline: Path) -> None:
    frames, options, series, rotation = recording
    options = options | ({"health"} if broken.endswith("health") else set())
    folder = tmp_path / f"broken-{TALLY.recordings['broken']}"
    folder.mkdir()
    path = write_sdk(folder / "run.rrd", frames, options, series, rotation, seed, broken)
    TALLY.recordings["broken"] += 1
    every_command(path, frames, folder, ground_truth, baseline, conforms=False)


def test_a_numeric_health_status_is_one_line_everywhere(tmp_path: Path, ground_truth: Path, baseline: Path) -> None:
    """The issue's case: `check` fails it, and `inspect`, `--json` and `compare` say why in one line."""
    path = write_sdk(tmp_path / "numeric.rrd", list(range(8)), {"health"}, set(), "mat3x3", 3, "numeric_health")
    for args in (("inspect", path), ("inspect", path, "--json"),
                 ("compare", baseline, path, "-o", tmp_path / "c.rrd")):
        result = vslam(*args)
        _one_line(result, args[0])
        # '0' (or '' in a process where a string `status` was logged before: Rerun keeps AnyValues' first type)
        assert "/health:status: '" in result.stderr and "is not a health level (ok, warn, fail)" in result.stderr


@pytest.mark.parametrize("writer", ["sdk", "framelog"])
def test_snapshot_of_an_accepted_recording(writer: str, tmp_path: Path) -> None:
    """`snapshot` needs the viewer (Vulkan): one plain-SDK recording and one of FrameLog, every optional entity."""
    need_vulkan()
    frames = list(range(5, 13))
    if writer == "sdk":
        path = write_sdk(tmp_path / "run.rrd", frames, set(ENTITIES), set(SERIES), "quaternion", 5)
    else:
        path = write_framelog(tmp_path / "run.rrd", frames, {"time", "image", "corners", "tracks", "inliers",
                                                             "health", "scalars", "gt"}, 5)
    assert vslam("check", path).returncode == 0
    result = vslam("snapshot", path, "--frame", "9", "--out", tmp_path / "shots", "--size", "320x240", "--view",
                   "all")
    assert result.returncode == 0, result.stderr
    assert (tmp_path / "shots" / "all.png").stat().st_size > 1000


def test_a_frame_timeline_of_durations_is_one_line_everywhere(tmp_path: Path, ground_truth: Path,
                                                              baseline: Path) -> None:
    """`set_time("frame", duration=…)` (not a sequence): `check` names it (it raised a TypeError itself), and every
    command, `snapshot` included (before any viewer starts), says so in one line."""
    path = write_sdk(tmp_path / "durations.rrd", list(range(8)), {"health"}, set(), "mat3x3", 3, "frame_duration")
    checked = vslam("check", path)
    assert checked.returncode == 1 and "timeline frame: a duration timeline, not a sequence" in checked.stdout
    for args in (("inspect", path), ("compare", baseline, path, "-o", tmp_path / "c.rrd"),
                 ("crop", path, "--frames", "2:5", "-o", tmp_path / "k.rrd"),
                 ("eval", "--trajectory", path, "--gt", ground_truth),
                 ("snapshot", path, "--frame", "3", "--out", tmp_path / "shots")):
        result = vslam(*args)
        _one_line(result, str(args[0]))
        assert "a duration timeline, not a sequence" in result.stderr
