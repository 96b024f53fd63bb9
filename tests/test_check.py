"""`vslam check`: recordings written with the plain Rerun SDK (as a C++ or other pipeline would), vslam's own run
recording, and files that are not recordings."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import rerun as rr
from cli_helpers import vslam

FRAMES = 12


def sdk_recording(path: Path, camera: str = "/world/camera", schema_version: str | None = "1",
                  hover: str = "frame_index", status: str = "ok") -> Path:
    """The schema's entities written with `rr.RecordingStream` alone (no vslam code): camera poses (quaternions,
    as a C++ pipeline might log them), health, a track series, the estimate, the run properties."""
    rec = rr.RecordingStream("my-cpp-vo")
    rec.save(path)
    properties = {"name": "my-cpp-vo kitti-05 frames 0:12", "source": "kitti-05", "frames": f"0:{FRAMES}",
                  "frame_count": str(FRAMES)}
    if schema_version is not None:
        properties["schema_version"] = schema_version
    rec.send_property("run", rr.AnyValues(**properties))
    rec.log("/world", rr.ViewCoordinates.RDF, static=True)
    for i in range(FRAMES):
        rec.set_time("frame", sequence=i)
        rec.set_time("time", duration=0.1 * i)
        rec.log(camera, rr.Transform3D(translation=[0.0, 0.0, float(i)], quaternion=rr.Quaternion(xyzw=[0, 0, 0, 1])))
        rec.log("/health", rr.AnyValues(status=status if i == 5 else "ok", reasons="few_matches" if i == 5 else ""))
        rec.log("/metrics/tracks/alive", rr.Scalars(100.0 + i))
        rec.log("/world/trajectory/estimate", rr.LineStrips3D([np.array([[0, 0, max(i - 1, 0)], [0, 0, i]], float)]))
    rec.log("/world/trajectory/gt_links", rr.LineStrips3D([np.zeros((2, 3))]), rr.AnyValues(**{hover: [0]}),
            static=True)
    rec.flush()
    rec.disconnect()
    return path


def test_a_plain_sdk_recording_conforms_and_inspect_reads_it(tmp_path: Path) -> None:
    path = sdk_recording(tmp_path / "sdk.rrd")
    result = vslam("check", path)
    assert result.returncode == 0, result.stdout + result.stderr
    assert result.stdout.strip() == f"{path}: conforms to recording schema 2 (6 entities, {FRAMES} frames 0..11)"
    report = json.loads(vslam("inspect", path, "--json").stdout)
    assert report["frames"]["count"] == FRAMES
    assert report["flagged"] == []  # status ok everywhere
    assert report["series"]["tracks_alive"]["max"] == 111.0


def test_a_misnamed_camera_fails_naming_both(tmp_path: Path) -> None:
    path = sdk_recording(tmp_path / "misnamed.rrd", camera="/world/cam")
    result = vslam("check", path)
    assert result.returncode == 1
    lines = result.stdout.splitlines()
    assert f"{path}: /world/camera: missing (required: T_world_cam per frame (world = camera frame of the first " \
           "frame, RDF, metres)) (affects inspect, compare, crop, repair, snapshot, open)" in lines
    assert any(line.startswith(f"{path}: /world/cam: not in recording schema 2: misnamed /world/camera?")
               for line in lines)
    assert lines[-1] == f"{path}: does not conform to recording schema 2: 2 problems"


def test_missing_version_clashing_component_and_bad_health_are_named(tmp_path: Path) -> None:
    path = sdk_recording(tmp_path / "bad.rrd", schema_version=None, hover="frame", status="broken")
    result = vslam("check", path)
    assert result.returncode == 1
    text = result.stdout
    assert "property schema_version: missing from /__properties/run" in text
    assert "/world/trajectory/gt_links:frame: a component named like the frame timeline (rename it, e.g. " \
           "frame_index) (affects inspect, compare, crop, open)" in text
    assert "/world/trajectory/gt_links: malformed: no frame_index" in text
    assert "/health:status: 'broken' is not a health level (ok, warn, fail) (affects inspect, compare)" in text
    newer = sdk_recording(tmp_path / "newer.rrd", schema_version="7")
    assert "schema_version: 7: newer than this vslam knows (2)" in vslam("check", newer).stdout


@pytest.mark.kitti
def test_a_vslam_run_conforms(kitti_root: Path, tmp_path: Path) -> None:
    path = tmp_path / "run.rrd"
    run = vslam("run", kitti_root, "--sequence", "05", "--frames", "0:12", "--detail", "standard", "-o", path)
    assert run.returncode == 0, run.stderr
    result = vslam("check", path)
    assert result.returncode == 0, result.stdout
    assert result.stdout.strip().endswith(f"{FRAMES} frames 0..11)")


def test_a_file_that_is_not_a_recording_is_one_line_exit_2(tmp_path: Path) -> None:
    text = tmp_path / "notes.rrd"
    text.write_text("not a recording\n")
    result = vslam("check", text)
    assert result.returncode == 2 and result.stdout == ""
    assert result.stderr.startswith(f"error: {text}: not a readable Rerun recording")
    assert len(result.stderr.strip().splitlines()) == 1
    missing = vslam("check", tmp_path / "nowhere.rrd")
    assert missing.returncode == 2 and missing.stderr.strip() == f"error: {tmp_path / 'nowhere.rrd'}: no such recording"
