"""`vslam compare`'s per-frame comparison: a planted divergence (KITTI 05's ground truth and a copy of it with one
step turned by a few degrees, both recorded by `vslam eval --trajectory … --images … --report`) is found at
exactly that frame, in the text, the JSON and the comparison recording; identical runs report none."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from cli_helpers import vslam

from vslam.compare.frames import frame_differences, read_run_frames
from vslam.rrd.read import read_entity
from vslam_core.trajectory.io import read_kitti_poses, write_kitti_poses

FRAMES = 40
KINK_FRAME, KINK_DEG = 23, 2.0


def with_kink(gt: np.ndarray, at: int | None, degrees: float) -> np.ndarray:
    """`gt` re-chained from its steps, the step of frame `at` turned by `degrees` about the camera's y axis."""
    c, s = np.cos(np.radians(degrees)), np.sin(np.radians(degrees))
    turn = np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])
    poses = [gt[0]]
    for i in range(1, len(gt)):
        step = np.linalg.inv(gt[i - 1]) @ gt[i]
        if i == at:
            step[:3, :3] = step[:3, :3] @ turn
        poses.append(poses[-1] @ step)
    return np.array(poses)


@pytest.fixture(scope="module")
def recordings(kitti_root: Path, tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    """Recordings of the unchanged and the kinked trajectory (one `eval` call), and their comparisons."""
    folder = tmp_path_factory.mktemp("divergence")
    gt = read_kitti_poses(kitti_root / "poses" / "05.txt", max_rows=FRAMES)
    write_kitti_poses(folder / "same.txt", with_kink(gt, None, 0.0))
    write_kitti_poses(folder / "kink.txt", with_kink(gt, KINK_FRAME, KINK_DEG))
    report = folder / "report"
    done = vslam("eval", "--trajectory", folder / "same.txt", "--trajectory", folder / "kink.txt", "--gt",
                 kitti_root / "poses" / "05.txt", "--match", "rows", "--frames", f"0:{FRAMES}",
                 "--images", kitti_root / "sequences" / "05",
                 "--report", report, "--detail", "summary")
    assert done.returncode == 0, done.stderr
    return {"same": report / "same.rrd", "kink": report / "kink.rrd", "folder": folder}


def test_planted_kink_is_the_first_divergence(recordings: dict[str, Path]) -> None:
    output = recordings["folder"] / "kink-vs-same.rrd"
    result = vslam("compare", recordings["same"], recordings["kink"], "-o", output, "--json")
    assert result.returncode == 0, result.stderr
    divergence = json.loads(result.stdout)["first_divergence"]
    assert divergence["frame"] == KINK_FRAME
    assert divergence["rotation_deg"] == pytest.approx(KINK_DEG, abs=0.01)
    assert divergence["translation_pct"] == pytest.approx(0.0, abs=0.01)  # the turn leaves the step's translation
    assert divergence["reasons_a"] == [] and divergence["reasons_b"] == []  # an external trajectory reports none
    assert [row["frame"] for row in divergence["context"]] == list(range(KINK_FRAME - 2, KINK_FRAME + 3))

    # read back from the comparison recording: the per-frame series, the marker and the event
    rotation = read_entity(output, "/compare/b/step_rotation_deg")
    values = dict(zip(rotation["frame"].to_list(), (v[0] for v in rotation["Scalars:scalars"].to_list()),
                      strict=True))
    assert sorted(values) == list(range(FRAMES))
    assert values[KINK_FRAME] == pytest.approx(KINK_DEG, abs=0.01)
    assert max(v for f, v in values.items() if f != KINK_FRAME) < 1e-3  # the other steps are the same
    position = read_entity(output, "/compare/b/position_m")
    apart = dict(zip(position["frame"].to_list(), (v[0] for v in position["Scalars:scalars"].to_list()),
                     strict=True))
    assert max(apart[f] for f in range(KINK_FRAME + 1)) < 1e-3  # the first frames aligned, then the same path
    assert apart[FRAMES - 1] > 0.1  # the kink swings the rest of the path
    marker = read_entity(output, "/compare/b/divergence")
    assert marker["frame"].to_list() == [KINK_FRAME]
    events = read_entity(output, "/compare/events")
    assert events["frame"].to_list() == [KINK_FRAME]
    assert [v[0] for v in events["TextLog:level"].to_list()] == ["WARN"]
    assert f"frame {KINK_FRAME}" in events["TextLog:text"].to_list()[0][0]

    text = vslam("compare", recordings["same"], recordings["kink"], "-o", output, "--force")
    assert text.returncode == 0, text.stderr
    assert f"first divergence  B vs A: frame {KINK_FRAME} (step rotation 2.00°" in text.stdout


def test_identical_runs_have_no_divergence(recordings: dict[str, Path]) -> None:
    output = recordings["folder"] / "same-vs-same.rrd"
    result = vslam("compare", recordings["same"], recordings["same"], "-o", output, "--json")
    assert result.returncode == 0, result.stderr
    report = json.loads(result.stdout)
    assert report["first_divergence"] is None
    assert report["divergence_thresholds"] == {"rotation_deg": 0.5, "translation_pct": 10.0}
    assert read_entity(output, "/compare/b/divergence").is_empty()
    rotation = read_entity(output, "/compare/b/step_rotation_deg")
    assert max(v[0] for v in rotation["Scalars:scalars"].to_list()) < 1e-6


def test_threshold_options_and_more_runs(recordings: dict[str, Path]) -> None:
    """A 2° kink is no divergence above 3°; with three runs each is compared with the first."""
    output = recordings["folder"] / "three.rrd"
    result = vslam("compare", recordings["same"], recordings["same"], recordings["kink"], "-o", output, "--json",
                   "--diverge-deg", "3")
    assert result.returncode == 0, result.stderr
    report = json.loads(result.stdout)
    assert report["first_divergences"] == {"B": None, "C": None}
    again = vslam("compare", recordings["same"], recordings["same"], recordings["kink"], "-o", output, "--json",
                  "--force")
    divergences = json.loads(again.stdout)["first_divergences"]
    assert divergences["B"] is None and divergences["C"]["frame"] == KINK_FRAME
    refused = vslam("compare", recordings["same"], recordings["kink"], "-o", output, "--force", "--diverge-deg", "-1")
    assert refused.returncode != 0 and "Traceback" not in refused.stderr


def test_frame_differences_of_read_back_poses(recordings: dict[str, Path]) -> None:
    """The module's own numbers: steps from poses read back from the files (Rerun's column-major rotation)."""
    same, kink = read_run_frames(recordings["same"]), read_run_frames(recordings["kink"])
    assert same.frames.tolist() == list(range(FRAMES))
    assert np.allclose(same.poses[:, :3, :3] @ same.poses[:, :3, :3].transpose(0, 2, 1), np.eye(3), atol=1e-5)
    differences = frame_differences(same, kink)
    assert int(np.argmax(differences.rotation_deg)) == KINK_FRAME
    assert differences.position_m[0] == 0.0
