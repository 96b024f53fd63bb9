"""The logging API's parts beyond poses (issue 54): named arrays with one-line errors, the four candidate poses
and triangulated points, the pipeline's own stages and plots (shown by `inspect` and `compare`), one recording id
per file, no overwrite without ``force=True``, and the underlying Rerun stream. Synthetic frames: no data needed."""

from __future__ import annotations

import json
import math
from pathlib import Path

import cv2
import numpy as np
import pytest
import rerun as rr
from cli_helpers import vslam

from vslam.log import CameraIntrinsics, Candidates, Corners, FrameLog, Tracks
from vslam.rrd import blueprint_view_names, read_entity
from vslam.rrd.provenance import read_properties

CAMERA = CameraIntrinsics(fx=700.0, fy=700.0, cx=600.0, cy=180.0, width=1200, height=360)


def _pose(i: int) -> np.ndarray:
    """Driving straight ahead 1 m a frame, from a world whose origin is 5 m to the right (re-based away)."""
    pose = np.eye(4)
    pose[:3, 3] = (5.0, 0.0, float(i))
    return pose


def _candidates() -> Candidates:
    """OpenCV's decomposition of the essential matrix of a 1° turn while driving forward, the true one chosen
    (120 points in front of both cameras, the others fewer)."""
    a = math.radians(1.0)
    rotation = np.array([[math.cos(a), 0, math.sin(a)], [0, 1, 0], [-math.sin(a), 0, math.cos(a)]])
    t = np.array([0.0, 0.0, -1.0])  # X_cur = R·X_prev + t: the camera moved forward
    skew = np.array([[0, -t[2], t[1]], [t[2], 0, -t[0]], [-t[1], t[0], 0]])
    R1, R2, t_unit = cv2.decomposeEssentialMat(skew @ rotation)  # noqa: N806
    four = Candidates.from_opencv(R1, R2, t_unit, in_front=[0, 0, 0, 0], chosen=0)
    # the true step T_prev_cur: rotation Rᵀ, translation (0, 0, 1) (forward)
    true = int(np.argmin([np.abs(r - rotation.T).sum() + np.abs(c - (0, 0, 1)).sum()
                          for r, c in zip(four.rotations, four.translations, strict=True)]))
    counts = [7, 3, 0]
    return Candidates(four.rotations, four.translations, [120 if k == true else counts.pop() for k in range(4)],
                      true)


def _log(path: Path, frames: int = 6, **options: object) -> None:
    ids = np.arange(50)
    prev, cur = np.full((50, 2), 300.0), np.full((50, 2), 305.0)
    with FrameLog(path, camera=CAMERA, source="street", pipeline="parts", **options) as log:  # type: ignore[arg-type]
        for i in range(frames):
            log.frame(i, pose=_pose(i), corners=Corners(px=cur, ids=ids),
                      tracks=Tracks(ids=ids, prev=prev, cur=cur) if i else None,
                      candidates=_candidates() if i else None, points=[[5.0, 0.0, i + 10.0], [6.0, 1.0, i + 12.0]],
                      timings_ms={"track": 2.0, "orb": 3.0 + i}, health="ok",
                      scalars={"counts/matches": 400 + i, "counts/keypoints": 900, "ratios/margin": 0.5,
                               "loose": 1.0})


def test_candidates_points_own_stages_and_plots_are_recorded_and_shown(tmp_path: Path) -> None:
    path = tmp_path / "parts.rrd"
    _log(path, detail="full")
    assert vslam("check", path).returncode == 0
    candidates = read_entity(path, "/world/candidates")
    chosen = candidates["chosen"].to_list()[-1].index(True)
    assert sorted(candidates["in_front"].to_list()[-1]) == [0, 3, 7, 120]
    centre = np.array(candidates["Points3D:positions"].to_list()[-1][chosen])
    # the chosen candidate's centre: the previous camera (z = 4) moved 1 m along its unit translation, which
    # points where the camera went (forward) as seen from the previous camera, Rᵀ·(0, 0, 1) for the 1° turn
    a = math.radians(1.0)
    assert np.allclose(centre, [-math.sin(a), 0.0, 4.0 + math.cos(a)], atol=1e-5)
    margin = read_entity(path, "/metrics/ransac/chirality_margin")
    assert [v[0] for v in margin["Scalars:scalars"].to_list()] == [113.0] * 5  # best − second, every frame but 0
    points = read_entity(path, "/world/points")
    last = np.array(points["Points3D:positions"].to_list()[-1])
    assert np.allclose(last, [[0.0, 0.0, 15.0], [1.0, 1.0, 17.0]])  # re-based like the poses (5 m to the left)
    report = json.loads(vslam("inspect", path, "--json").stdout)
    assert report["stages_ms"]["orb"]["mean"] == pytest.approx(5.5)  # the pipeline's own stage beside vslam's
    assert report["stages_ms"]["track"]["mean"] == pytest.approx(2.0)
    own = report["own_series"]
    assert set(own) == {"counts", "ratios", "pipeline series"}
    assert own["counts"]["matches"]["max"] == 405 and own["pipeline series"]["loose"]["mean"] == 1.0
    text = vslam("inspect", path).stdout
    assert "counts: matches" in text and "orb " in text
    views = blueprint_view_names(path)
    assert views is not None and {"pipeline series", "counts", "ratios"} <= set(views)
    compared = vslam("compare", path, path, "-o", tmp_path / "c.rrd", "--json")
    assert compared.returncode == 0, compared.stderr
    compared_views = blueprint_view_names(tmp_path / "c.rrd")  # the runs' own plots overlaid, as the others
    assert compared_views is not None and {"pipeline series", "counts", "ratios"} <= set(compared_views)
    differences = json.loads(compared.stdout)["differences"]["B"]
    assert differences["own_series.counts.matches.mean"]["value"] == pytest.approx(402.5)
    assert differences["stages_ms.orb.mean"]["difference"] == 0.0


def test_named_arrays_and_tuples_are_the_same_and_wrong_shapes_say_what_was_expected(tmp_path: Path) -> None:
    ids, prev, cur = np.arange(4), np.zeros((4, 2)), np.ones((4, 2))
    for name, tracks in (("named", Tracks(ids=ids, prev=prev, cur=cur)), ("tuple", (ids, prev, cur))):
        with FrameLog(tmp_path / f"{name}.rrd", camera=CAMERA, source="s", detail="summary") as log:
            log.frame(0, pose=np.eye(4))
            log.frame(1, pose=np.eye(4), tracks=tracks)
    assert (read_entity(tmp_path / "named.rrd", "/metrics/tracks/alive")["Scalars:scalars"].to_list()
            == read_entity(tmp_path / "tuple.rrd", "/metrics/tracks/alive")["Scalars:scalars"].to_list() == [[4.0]])
    log = FrameLog(tmp_path / "bad.rrd", camera=CAMERA, source="s")
    cases = [
        ({"tracks": Tracks(ids=ids, prev=np.zeros((4, 3)), cur=cur)}, r"tracks\.prev: expected \(M, 2\) pixels, got "
                                                                      r"shape \(4, 3\)"),
        ({"tracks": (ids, prev)}, r"tracks: expected Tracks\(ids=\(M,\), prev=\(M, 2\), cur=\(M, 2\)\)"),
        ({"tracks": Tracks(ids=ids[:3], prev=prev, cur=cur)},
         "tracks: expected M rows in each of ids, prev and cur, got 3, 4 and 4"),
        ({"corners": Corners(px=np.zeros(5))}, r"corners\.px: expected \(K, 2\) pixels, got shape \(5,\)"),
        ({"candidates": (1, 2)}, r"candidates: expected vslam\.log\.Candidates"),
        ({"candidates": Candidates(np.zeros((4, 3, 3)), np.zeros((4, 3)), [1, 2, 3, 4], 0)},
         r"candidates\.rotations\[0\]: expected a rotation"),
        ({"points": np.zeros((3, 2))}, r"points: expected \(P, 3\) points in the world, got shape \(3, 2\)"),
        ({"scalars": {"a/b/c": 1.0}}, "series name 'a/b/c': name or plot/name"),
        ({"timings_ms": {"orb": "fast"}}, r"timings_ms\['orb'\]: expected a number"),
    ]
    for arguments, message in cases:
        with pytest.raises(ValueError, match=f"^frame 0: {message}") as raised:
            log.frame(0, pose=np.eye(4), **arguments)  # type: ignore[arg-type]
        assert "\n" not in str(raised.value)
    log.frame(0, pose=np.eye(4), scalars={"counts/matches": 1.0})
    with pytest.raises(ValueError, match="plot 'ratios' is new .* counts"):  # the layout is written at frame 0
        log.frame(1, pose=np.eye(4), scalars={"ratios/margin": 0.5})
    log.close()


def test_one_recording_id_per_file_and_no_overwrite_without_force(tmp_path: Path) -> None:
    for folder in ("before", "after"):
        (tmp_path / folder).mkdir()
        _log(tmp_path / folder / "run.rrd", frames=3, detail="summary")
    ids = {read_properties(tmp_path / folder / "run.rrd", "/__properties/run")["recording_id"]
           for folder in ("before", "after")}
    assert len(ids) == 2  # the viewer would merge two recordings that shared one
    path = tmp_path / "before" / "run.rrd"
    size = path.stat().st_size
    with pytest.raises(FileExistsError, match=r"exists already \(FrameLog\(\.\.\., force=True\) replaces it\)"):
        FrameLog(path, camera=CAMERA, source="s")
    assert path.stat().st_size == size  # untouched
    _log(path, frames=2, detail="summary", force=True)
    assert json.loads(vslam("inspect", path, "--json").stdout)["frames"]["count"] == 2


def test_the_underlying_stream_logs_what_the_schema_does_not_cover(tmp_path: Path) -> None:
    path = tmp_path / "stream.rrd"
    with FrameLog(path, camera=CAMERA, source="s", detail="summary") as log:
        with pytest.raises(ValueError, match="log a frame first"):
            _ = log.stream
        for i in range(3):
            log.frame(i, pose=_pose(i))
            log.stream.set_time("frame", sequence=i)
            log.stream.log("/my/loop_score", rr.Scalars(0.1 * i))
    table = read_entity(path, "/my/loop_score")
    assert table["frame"].to_list() == [0, 1, 2]
    assert vslam("check", path).returncode == 0
