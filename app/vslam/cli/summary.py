"""The summary `vslam run` prints: what was run, on which camera and scale, and how well it did."""

from __future__ import annotations

from typing import TYPE_CHECKING

from vslam.cli.common import out

if TYPE_CHECKING:
    from vslam_core.config import EngineConfig
    from vslam_core.pipeline import RunResult
    from vslam_core.sources.base import FrameSource
    from vslam_core.trajectory.gt_check import CheckSummary


def held_reasons(run: RunResult) -> str:
    """``: stationary 299`` — why frames were held, most frequent first (empty when none was)."""
    ranked = sorted(run.held_reasons.items(), key=lambda item: (-item[1], item[0]))
    return (": " + ", ".join(f"{reason} {count}" for reason, count in ranked)) if ranked else ""


def print_summary(source: FrameSource, run: RunResult, config: EngineConfig, in_map: bool = False,
                  gt_check: CheckSummary | None = None) -> None:
    """`vslam run`'s summary on stdout: frames and why some were held, time, backend, scale source, camera and
    where its calibration came from, how ground truth was paired, and the accuracy against it (`in_map`: the
    poses are in a prior map's frame, so they are not scored against this run's ground truth); `gt_check`: the
    ground truth against the images (its warnings are the caller's)."""
    import numpy as np

    from vslam.common import scored_estimate
    from vslam_core.config import describe_pixel_scale
    from vslam_core.scale import default_camera_height
    from vslam_core.sources.base import ground_truth_matching
    from vslam_core.sources.calibration import camera_line
    from vslam_core.trajectory.metrics import ate, kitti_errors, paper_rms_error, scale_errors, stands_still

    fps = run.frames / run.seconds if run.seconds > 0 else float("nan")
    lines = [
        f"frames      {run.frames} ({run.held_summary}" + held_reasons(run) + ")",
        f"time        {run.seconds:.1f} s, {fps:.1f} frames/s",
        f"backend     {config.backend}",
        f"scale       {config.scale}"
        + (f" (camera {default_camera_height(source.camera_height, config):.2f} m above the road; no ground truth "
           "used)" if config.scale == "height" else ""),
    ]
    if (road := run.road_summary) is not None:
        lines.append(f"road plane  {road}")
    if (placed := run.placed_summary(config.scale)) is not None:
        lines.append(f"placed      {placed}")
    if (settings := run.settings_summary(config.scale)) is not None:
        lines.append(f"settings    {settings}")
    if (adjusted := run.adjusted_summary) is not None:
        lines.append(f"adjusted    {adjusted}")
    lines.append(f"camera      {camera_line(source.intrinsics)}")
    if (scaled := describe_pixel_scale(config, source.intrinsics.width)) is not None:
        lines.append(f"pixels      {scaled}")
    gt = source.ground_truth
    if in_map and gt is not None:  # poses in the prior map's frame, ground truth in this run's first frame's
        lines.append("accuracy    not scored here: the poses are in the prior map's frame (see README, Saving a map)")
        gt = None
    if (matching := ground_truth_matching(source)) is not None:
        lines.append(f"ground truth {matching}")
    if gt_check is not None:
        lines.append(f"gt check    {gt_check.line()}")
    if gt is not None and run.frames > 1:
        gt, poses = gt[: run.frames], run.pose_array()
        if config.scale == "height":
            median, _, path = scale_errors(gt, poses)
            lines.append(f"step length {median:+.1f} % median error per frame, path length {path:+.1f} % vs ground "
                         "truth")
        scored = scored_estimate(gt, poses, config.scale)  # --scale none: Sim(3)-aligned, as eval
        aligned = config.scale == "none"
        t_err, r_err = kitti_errors(gt, scored)
        lines.append("KITTI       " + ("t_err —   r_err —   (path < 100 m: no segment)" if np.isnan(t_err) else
                                      f"t_err {t_err:.2f} %   r_err {r_err:.2f} °/100 m")
                     + ("   (after Sim(3) alignment: --scale none has no metric scale)" if aligned else ""))
        # ATE: 3-D RMSE of the positions (Sturm et al. 2012), a hand-held camera's measure
        lines.append("ATE         " + ("" if aligned else f"{ate(gt, poses, 'none'):.3f} m without alignment, ")
                     + ("— after Sim(3) (the estimate does not move)" if stands_still(poses) else
                        f"{ate(gt, poses, 'sim3'):.3f} m after Sim(3)") + f" (3-D RMSE over {len(gt)} frames)")
        lines.append(f"paper RMS   {paper_rms_error(gt, scored):.2f} m (x–z, "
                     + ("after Sim(3) alignment)" if aligned else "no alignment)"))
        lines.append("scored      " + ("the map's refined poses (after bundle adjustment and loop closing), as "
                                      "--trajectory-out holds them and `vslam inspect` scores them"
                                      if run.scored_trajectory == "refined" else "the poses as tracked"))
    out.print("\n".join(lines), highlight=False)
