"""Entities of loop closing (`--backend map`, vslam_core/loop/), logged at the keyframes that searched for one,
and at the last frame for the searches collected when the run ended (`RunResult.loops_at_end`).

    /loops/candidates                   AnyValues, one instance per candidate checked at this keyframe:
                                        query_frame, candidate_frame (source frame indices), score, matches,
                                        inliers, accepted, why
    /loops/candidate/image              EncodedImage (JPEG at the camera frames' quality): the query keyframe
                                        (left) and its best candidate (right), half size, side by side
                                        (standard and full detail)
    /loops/candidate/image/matches      LineStrips2D on it: each descriptor match to a landmark the candidate
                                        saw itself, class inlier / outlier
    /loops/closed                       AnyValues per closed loop: query_frame, candidate_frame, inliers,
                                        correction_m, correction_deg (of the query keyframe: the largest),
                                        similarity (Sim(3) graph)
    /loops/correction_m, _deg           BarChart: the correction applied to each keyframe of the pose graph
    /world/loops/edges                  LineStrips3D: every accepted loop edge between the two keyframes
                                        (corrected positions), re-logged with all loops so far
    /world/loops/before, /after         LineStrips3D: the keyframe path before and after the correction
    /events                             each candidate (accepted or why not) and each closed loop
"""

from __future__ import annotations

import numpy as np
import rerun as rr

from vslam.recording.columns import EVENTS, EVENTS_AT_END, UNIX_STAMPS_AFTER_S, ColumnBuffer, add_event
from vslam.recording.levels import JPEG_QUALITY, Detail
from vslam.recording.video import encode_jpeg
from vslam_core.results import LoopCandidate, LoopStep
from vslam_core.sources.base import Frame

INLIER, OUTLIER = 1, 0
MATCH_STYLE = {OUTLIER: ("loop match outlier", (230, 30, 30)), INLIER: ("loop match inlier", (40, 220, 60))}
EDGE_COLOUR = (255, 0, 200)
BEFORE_COLOUR = (150, 150, 150)
AFTER_COLOUR = (0, 200, 255)


class LoopRecording:
    """Logs what loop closing did at each keyframe."""

    def __init__(self, rec: rr.RecordingStream, columns: ColumnBuffer, detail: Detail,
                 jpeg_quality: int = JPEG_QUALITY) -> None:
        """`jpeg_quality`: of the candidate image (the camera frames')."""
        self._rec = rec
        self._jpeg_quality = jpeg_quality
        self._columns = columns
        self._detail = detail
        self._indices: dict[int, int] = {}  # run position -> source frame index
        self._edges: list[np.ndarray] = []
        self.closed: list[tuple[int, int]] = []  # (query frame, candidate frame) of each closed loop
        rec.log("/world/loops/edges", rr.LineStrips3D.from_fields(radii=0.15, colors=EDGE_COLOUR), static=True)
        rec.log("/world/loops/before", rr.LineStrips3D.from_fields(radii=0.06, colors=BEFORE_COLOUR), static=True)
        rec.log("/world/loops/after", rr.LineStrips3D.from_fields(radii=0.08, colors=AFTER_COLOUR), static=True)
        rec.log("/loops/candidate/image/matches", rr.AnnotationContext(
            [(class_id, label, colour) for class_id, (label, colour) in MATCH_STYLE.items()]), static=True)

    def log_frame(self, frame: Frame, position: int, step: LoopStep | None, at_end: bool = False) -> None:
        """`at_end`: a search that finished when the run ended (its events go to `EVENTS_AT_END`)."""
        self._indices[position] = frame.index
        if step is None:
            return
        events = EVENTS_AT_END if at_end else EVENTS
        if step.candidates:
            self._log_candidates(frame, step.candidates, events)
        closed = step.closed
        if closed is None:
            return
        query, candidate = self._index(closed.query_position), self._index(closed.candidate_position)
        newest = int(np.flatnonzero(closed.keyframe_ids == closed.query_keyframe)[0])
        after = {int(k): p for k, p in zip(closed.keyframe_ids, closed.poses_after, strict=True)}
        self._edges.append(np.array([after[closed.candidate_keyframe][:3, 3], after[closed.query_keyframe][:3, 3]],
                                    np.float32))
        self.closed.append((query, candidate))
        self._set_time(frame)
        rec = self._rec
        rec.log("/loops/closed", rr.AnyValues(
            query_frame=query, candidate_frame=candidate, inliers=closed.inliers,
            correction_m=float(closed.correction_m[newest]), correction_deg=float(closed.correction_deg[newest]),
            similarity=closed.similarity))
        rec.log("/loops/correction_m", rr.BarChart(closed.correction_m.astype(np.float64)))
        rec.log("/loops/correction_deg", rr.BarChart(closed.correction_deg.astype(np.float64)))
        rec.log("/world/loops/edges", rr.LineStrips3D(self._edges))
        rec.log("/world/loops/before", rr.LineStrips3D([closed.poses_before[:, :3, 3].astype(np.float32)]))
        rec.log("/world/loops/after", rr.LineStrips3D([closed.poses_after[:, :3, 3].astype(np.float32)]))
        rec.reset_time()
        add_event(self._columns, frame, f"loop closed: frame {query} revisits frame {candidate} ({closed.inliers} "
                  f"inliers); {len(closed.keyframe_ids)} keyframes corrected, up to "
                  f"{closed.correction_m.max():.2f} m and {closed.correction_deg.max():.2f}°, "
                  f"{closed.landmarks_moved} landmarks moved", "INFO", events)

    def _index(self, position: int) -> int:
        return self._indices.get(position, position)

    def _log_candidates(self, frame: Frame, candidates: tuple[LoopCandidate, ...], events: str) -> None:
        rows = {
            "query_frame": np.array([self._index(c.query_position) for c in candidates], np.int64),
            "candidate_frame": np.array([self._index(c.candidate_position) for c in candidates], np.int64),
            "score": np.array([c.score for c in candidates], np.float64),
            "matches": np.array([c.matches for c in candidates], np.int64),
            "inliers": np.array([c.inliers for c in candidates], np.int64),
            "accepted": np.array([c.accepted for c in candidates], bool),
            "why": [c.why for c in candidates],
        }
        self._columns.add("/loops/candidates", frame, (rr.AnyValues.columns, rows), batch=True)
        for c in candidates:
            add_event(self._columns, frame, f"loop candidate: frame {self._index(c.query_position)} vs frame "
                      f"{self._index(c.candidate_position)} (score {c.score:.3f}): {c.matches} matches, {c.inliers} "
                      f"inliers, {'accepted' if c.accepted else 'rejected: ' + c.why}",
                      "INFO" if c.accepted else "DEBUG", events)
        if self._detail == Detail.SUMMARY:
            return
        best = max(candidates, key=lambda c: (c.accepted, c.inliers, c.matches))
        if best.query_image is None or best.candidate_image is None:
            return
        self._set_time(frame)
        left, right = best.query_image, best.candidate_image
        height = max(left.shape[0], right.shape[0])
        side = np.zeros((height, left.shape[1] + right.shape[1]), np.uint8)
        side[: left.shape[0], : left.shape[1]] = left
        side[: right.shape[0], left.shape[1]:] = right
        shown = np.isfinite(best.candidate_pixels).all(axis=1)  # matches to a neighbour's landmark: not drawn
        half_query = best.query_pixels[shown].astype(np.float32) * 0.5
        half_candidate = (best.candidate_pixels[shown].astype(np.float32) * 0.5
                          + np.array([left.shape[1], 0], np.float32))
        # JPEG, not raw pixels: ~15 KB instead of ~70 KB (LZ4 of 2 x 620 x 188 grey) at each keyframe that
        # searched, a map run's largest entity after the camera frames and the flow arrows
        jpeg = encode_jpeg(side, 1.0, self._jpeg_quality, what="a loop candidate image")
        self._rec.log("/loops/candidate/image", rr.EncodedImage(contents=jpeg, media_type=rr.MediaType.JPEG))
        self._rec.log("/loops/candidate/image/matches", rr.LineStrips2D(
            list(np.stack([half_query, half_candidate], axis=1)), radii=0.6,
            class_ids=np.where(best.inlier_mask[shown], INLIER, OUTLIER).astype(np.uint16)))
        self._rec.reset_time()

    def _set_time(self, frame: Frame) -> None:
        self._rec.set_time("frame", sequence=frame.index)
        if frame.timestamp is not None:  # as the column buffer's `time` timeline
            if frame.timestamp > UNIX_STAMPS_AFTER_S:
                self._rec.set_time("time", timestamp=frame.timestamp)
            else:
                self._rec.set_time("time", duration=frame.timestamp)
