"""The trajectory a run is scored on, in the recording: the poses the run ended with.

The map backend refines every frame's pose after it was tracked (bundle adjustment, loop closing: `RunResult.poses`
then holds the refined poses, `RunResult.tracked_poses` the tracking-time ones). `--trajectory-out`, `vslam eval`
and the run summary score the refined poses, so the recording's errors must be of them too: with the map (and
with `--scale none`, whose estimate is Sim(3)-aligned first) the error series are logged when the run ends, of
the scored estimate, not frame by frame as tracked.

    /world/trajectory/estimate_refined  static, when the map refined the poses: the refined path (the scored one;
                                        `/world/camera` and `/world/trajectory/estimate` stay as tracked)
    /world/trajectory/estimate_sim3     static, --scale none: the scored estimate after Sim(3) alignment
    /metrics/error/position_m           at the end (map or --scale none): each frame's position error of it
    /metrics/angle_error/heading_deg    at the end (map): each frame's heading error of it
"""

from __future__ import annotations

import numpy as np
import rerun as rr

from vslam.common import scored_estimate
from vslam.recording.styles import ESTIMATE_COLOUR
from vslam_core.pipeline import RunResult
from vslam_core.trajectory.metrics import heading_errors

ALIGNED_ERROR = "/metrics/error/position_m"
ALIGNED_ESTIMATE = "/world/trajectory/estimate_sim3"
REFINED_ESTIMATE = "/world/trajectory/estimate_refined"
HEADING_ERROR = "/metrics/angle_error/heading_deg"
#: The colour of the refined path: the estimate's, lighter (drawn beside the path as tracked).
REFINED_COLOUR = (255, 170, 120)


def scored_line(run: RunResult, scale: str) -> str:
    """One line saying which poses every number of the run is of."""
    which = ("the map's refined poses (after bundle adjustment and loop closing), as --trajectory-out holds them; "
             "/world/camera and the path drawn while running are the poses as tracked"
             if run.scored_trajectory == "refined" else "the poses as tracked (nothing refined them)")
    return f"Scored: {which}" + (", after Sim(3) alignment." if scale == "none" else ".")


def log_scored(rec: rr.RecordingStream, gt: np.ndarray, run: RunResult, scale: str, at_end: bool) -> np.ndarray:
    """Log the scored estimate's entities (`at_end`: the map backend, whose error series were left for now) and
    return it (N, 4, 4): the run's poses, Sim(3)-aligned onto `gt` (N, 4, 4) with --scale none."""
    poses = run.pose_array()
    scored = scored_estimate(gt, poses, scale)
    frames = [rr.TimeColumn("frame", sequence=list(run.indices))]
    if run.tracked_poses:
        rec.log(REFINED_ESTIMATE, rr.LineStrips3D([poses[:, :3, 3]], colors=REFINED_COLOUR, radii=0.08,
                                                  labels=["estimate refined by the map (scored)"]), static=True)
    if scale == "none" or at_end:
        errors = np.linalg.norm(scored[:, :3, 3] - gt[:, :3, 3], axis=1)
        name = "position error after Sim(3) alignment (m)" if scale == "none" else "position error, refined (m)"
        rec.log(ALIGNED_ERROR, rr.SeriesLines(names=name, colors=ESTIMATE_COLOUR), static=True)
        rec.send_columns(ALIGNED_ERROR, indexes=frames, columns=rr.Scalars.columns(scalars=errors))
    if at_end:  # the heading needs no alignment: of the poses themselves
        rec.send_columns(HEADING_ERROR, indexes=frames, columns=rr.Scalars.columns(scalars=heading_errors(gt, poses)))
    if scale == "none":
        rec.log(ALIGNED_ESTIMATE, rr.LineStrips3D([scored[:, :3, 3]], colors=ESTIMATE_COLOUR, radii=0.12,
                                                  labels=["estimate after Sim(3) alignment"]), static=True)
    return scored
