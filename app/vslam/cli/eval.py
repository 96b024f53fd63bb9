"""`vslam eval`: score the engine on sources, or any trajectory file, against ground truth (registered on
the app by `vslam.cli.commands`)."""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Any

import typer

from vslam.cli.common import (
    BACKEND_HELP,
    CALIB_HELP,
    CALIB_SCALE_HELP,
    CAMERA_HEIGHT_HELP,
    GT_HELP,
    GT_ROWS_HELP,
    GT_TIME_OFFSET_HELP,
    GT_TOLERANCE_HELP,
    GT_TOPIC_HELP,
    IMAGE_CODEC_HELP,
    TOPIC_HELP,
    Backend,
    BadFrame,
    Scale,
    TrajectoryFormat,
    err,
    fail,
    out,
    print_error,
    report_writes,
    warn,
)
from vslam.evaluation import DEFAULT_TOLERANCE_MS, MatchMode
from vslam.recording import DEFAULT_DETAIL, Detail, ImageCodec

if TYPE_CHECKING:
    from vslam.evaluation import Evaluation
    from vslam_core.sources.base import FrameSource

MANIFEST_HELP = ("many logs, one a row: CSV (or TOML [[log]]) with name, source and columns named like the vslam "
                 "run options (docs/batches.md)")
WORKERS_HELP = "--manifest: local worker processes [default: the cores, capped by memory]"
RAY_HELP = "--manifest: run each log as a task on this Ray cluster (needs vslam[cluster])"
SHARD_HELP = "--manifest: run only slice K of N (1-based: manifest rows i with i % N == K-1)"
MERGE_HELP = "merge these shard reports (--merge DIR DIR …) into --report"


def eval_command(
    ctx: typer.Context,
    source: Annotated[str | None, typer.Argument(help="KITTI root (with --sequences), sequence folder, ROS "
                                                 "bag / MCAP log or EuRoC folder with ground truth, image folder "
                                                 "with --gt, or 'synthetic'")] = None,
    sequences: Annotated[str | None, typer.Option(help="KITTI sequences, e.g. 00,05")] = None,
    frames: Annotated[str | None, typer.Option(help="START:END[:STEP] of every sequence (END excluded; an END past "
                                               "the last frame is clamped to it, like a Python slice); with "
                                               "--trajectory: the frames (ground-truth rows) the file holds")]
    = None,
    time_offset: Annotated[float | None, typer.Option(help="--trajectory: seconds added to the file's timestamps "
                                                      "to put them on the ground truth's clock")] = None,
    scale: Annotated[Scale, typer.Option(help="gt: ground-truth step length; height: from the known camera "
                                         "height (no ground truth used); none: unit steps, scored after Sim(3) "
                                         "alignment")] = Scale.gt,
    camera_height: Annotated[float | None, typer.Option(help=CAMERA_HEIGHT_HELP)] = None,
    backend: Annotated[Backend | None, typer.Option(help=BACKEND_HELP)] = None,
    config_file: Annotated[Path | None, typer.Option("--config", help="engine config (TOML)")] = None,
    report: Annotated[Path | None, typer.Option(help="folder for metrics.csv/.parquet, report.md, trajectories, "
                                                "recordings and plots")] = None,
    detail: Annotated[Detail, typer.Option(help="detail of the recordings written to --report")] = DEFAULT_DETAIL,
    image_codec: Annotated[ImageCodec, typer.Option(help=IMAGE_CODEC_HELP)] = ImageCodec.JPEG,
    trajectory: Annotated[list[Path] | None, typer.Option(help="evaluate this trajectory file instead of running "
                                                          "(repeat for several, all against --gt)")] = None,
    images: Annotated[Path | None, typer.Option(help="the camera frames of --trajectory files, for their "
                                                "recordings: an image folder or a KITTI sequence folder (row i is "
                                                "image i, or matched by timestamp like the ground truth)")] = None,
    gt: Annotated[Path | None, typer.Option(help="ground truth for --trajectory, or of a SOURCE: " + GT_HELP)] = None,
    intrinsics: Annotated[str | None, typer.Option(help="fx,fy,cx,cy of an image folder, video or log SOURCE")]
    = None,
    calib: Annotated[Path | None, typer.Option(help=CALIB_HELP)] = None,
    calib_scale: Annotated[float | None, typer.Option(min=0.01, max=100.0, help=CALIB_SCALE_HELP)] = None,
    topic: Annotated[str | None, typer.Option(help=TOPIC_HELP)] = None,
    gt_topic: Annotated[str | None, typer.Option(help=GT_TOPIC_HELP)] = None,
    gt_times: Annotated[Path | None, typer.Option(help="timestamps of a KITTI --gt (the sequence's times.txt, "
                                                  "line i = pose row i): TUM rows are then matched by time")]
    = None,
    match: Annotated[MatchMode, typer.Option(help="--trajectory rows: auto = by timestamp when both sides have "
                                             "times, else row by row if the files have the same length; "
                                             "timestamps; rows = row i is frame i, whatever the lengths")]
    = MatchMode.auto,
    time_tolerance: Annotated[float | None, typer.Option("--time-tolerance", "--gt-tolerance", min=0.0,
                                                         help=GT_TOLERANCE_HELP + " (--trajectory rows and SOURCE "
                                                         "frames) [default: 10]")] = None,
    gt_time_offset: Annotated[float | None, typer.Option(help=GT_TIME_OFFSET_HELP + " (SOURCE frames)")] = None,
    gt_rows: Annotated[str | None, typer.Option(help=GT_ROWS_HELP + " (SOURCE frames)")] = None,
    trajectory_format: Annotated[TrajectoryFormat | None, typer.Option("--format", help="kitti or tum "
                                                                       "[default: from the columns]")] = None,
    as_json: Annotated[bool, typer.Option("--json", help="print the metrics as JSON (keys in docs/evaluation.md)")]
    = False,
    max_t_err: Annotated[float | None, typer.Option(help="gate: fail if any sequence's t_err (%) is above")] = None,
    max_r_err: Annotated[float | None, typer.Option(help="gate: fail if any r_err (°/100 m) is above")] = None,
    max_ate: Annotated[float | None, typer.Option(help="gate: fail if any ATE Sim(3) (m) is above")] = None,
    inject: Annotated[str | None, typer.Option(help="fault injection on every sequence (see vslam run)")] = None,
    on_bad_frame: Annotated[BadFrame, typer.Option(help="unreadable image: fail or skip")] = BadFrame.fail,
    force: Annotated[bool, typer.Option("--force", help="write into a --report folder that holds a report")]
    = False,
    manifest: Annotated[Path | None, typer.Option(metavar="LOGS.csv", help=MANIFEST_HELP)] = None,
    workers: Annotated[int | None, typer.Option(min=1, metavar="N", help=WORKERS_HELP)] = None,
    ray_address: Annotated[str | None, typer.Option(envvar="RAY_ADDRESS", metavar="HOST:PORT", help=RAY_HELP)]
    = None,
    shard: Annotated[str | None, typer.Option(metavar="K/N", help=SHARD_HELP)] = None,
    resume: Annotated[bool, typer.Option("--resume", help="--manifest: skip the logs that finished ok in --report "
                                         "(failed ones run again)")] = False,
    fail_fast: Annotated[bool, typer.Option("--fail-fast", help="--manifest: stop at the first failed log")]
    = False,
    merge: Annotated[list[Path] | None, typer.Option(metavar="DIR", help=MERGE_HELP)] = None,
) -> None:
    """Score the engine (or any trajectory file) against ground truth; gates make it a CI check."""
    if manifest is not None or merge:
        _eval_batch({**locals(), "extra": list(ctx.args)})
        return
    if ctx.args:
        fail(f"unexpected argument {ctx.args[0]!r} (only --merge takes several folders)")
    from_env = ray_address is not None and ray_address == os.environ.get("RAY_ADDRESS")  # not asked for here
    if any((workers, ray_address and not from_env, shard, resume, fail_fast)):
        fail("--workers, --ray-address, --shard, --resume and --fail-fast apply to --manifest batches")
    if report is not None:
        _check_report_dir(report, force)
    if images is not None and not trajectory:
        fail("--images shows the camera frames of --trajectory files: a SOURCE has its own")
    if trajectory:
        if source is not None or sequences is not None:
            fail("give either SOURCE or --trajectory, not both")
        if gt is None:
            fail("--trajectory needs --gt (the ground-truth poses to compare with)")
        if backend is not None:
            fail("--backend chooses how the engine runs: it does not apply to --trajectory files")
        engine_options = {"--inject": inject, "--config": config_file, "--camera-height": camera_height,
                          "--gt-time-offset": gt_time_offset, "--gt-rows": gt_rows}
        for option in (name for name, value in engine_options.items() if value is not None):
            fail(f"{option} applies to runs of the engine: it does not apply to --trajectory files")
        if calib_scale is not None:
            fail("--calib-scale resizes a SOURCE's calibration: it does not apply to --trajectory files")
        if topic is not None or gt_topic is not None or (images is None and (intrinsics or calib)):
            fail("--intrinsics, --calib, --topic and --gt-topic describe a SOURCE: they do not apply to --trajectory "
                 "files (--intrinsics and --calib do to their --images)")
        from vslam.cli.external import evaluate_external

        fmt = trajectory_format.value if trajectory_format is not None else None
        assert gt is not None
        evaluation = evaluate_external(trajectory, gt, fmt, report, detail,  # type: ignore[arg-type]
                                       images, intrinsics, calib, gt_times, match,
                                       DEFAULT_TOLERANCE_MS if time_tolerance is None else time_tolerance,
                                       frames, time_offset)
        scale_source = backend_name = "external"
    else:
        if gt_times is not None or match is not MatchMode.auto or time_offset is not None:
            fail("--gt-times, --match and --time-offset apply to --trajectory files only")
        from vslam.runs import input_warnings, with_camera_height
        from vslam_core.config import EngineConfig
        from vslam_core.config_file import load_config
        from vslam_core.sources.base import FrameRange
        from vslam_core.sources.open import open_source

        config = load_config(config_file) if config_file is not None else EngineConfig()
        config = config.with_scale(scale.value)
        if backend is not None:
            config = config.with_backend(backend.value)
        frame_range = FrameRange.parse(frames)
        if sequences is not None:
            if source is None:
                fail("--sequences needs SOURCE, the KITTI dataset root")
            if gt_time_offset is not None or gt_rows is not None:
                fail("--gt-time-offset and --gt-rows do not apply to KITTI --sequences (poses/NN.txt is paired row "
                     "by row, line i = image i)")
            if any(o is not None for o in (intrinsics, calib, calib_scale, topic, gt_topic)):
                fail("--intrinsics, --calib, --calib-scale, --topic and --gt-topic do not apply to KITTI --sequences "
                     "(they have calib.txt and poses)")
            sources: list[FrameSource] = [
                open_source(source, sequence=s.strip(), frames=frame_range, ground_truth=gt,
                            on_bad_frame=on_bad_frame.value, inject=inject,
                            gt_tolerance_s=None if time_tolerance is None else time_tolerance / 1000.0)
                for s in sequences.split(",") if s.strip()
            ]
        else:
            sources = [open_source(source, frames=frame_range, intrinsics=intrinsics, calib=calib, ground_truth=gt,
                                   on_bad_frame=on_bad_frame.value, inject=inject, topic=topic, gt_topic=gt_topic,
                                   gt_tolerance_s=None if time_tolerance is None else time_tolerance / 1000.0,
                                   calib_scale=calib_scale, gt_time_offset_s=gt_time_offset, gt_rows=gt_rows)]
        for src in sources:
            config = with_camera_height(config, camera_height, src)
        for warning in dict.fromkeys(w for src in sources for w in input_warnings(src, config)):
            warn(warning)
        from vslam.evaluation import evaluate_sources  # here: it loads the engine, the recorder and polars

        with report_writes(report):
            evaluation = evaluate_sources(sources, config, report, err, detail if report is not None else Detail.OFF,
                                          {"source_path": source or "synthetic", **({"inject": inject} if inject
                                                                                    else {})}, image_codec)
        scale_source, backend_name = config.scale, config.backend
        if not as_json:  # how each source's ground truth was paired with its frames (by time, row by row)
            from vslam_core.sources.base import ground_truth_matching

            for src in sources:
                if (matching := ground_truth_matching(src)) is not None:
                    out.print((f"{src.name}: " if len(sources) > 1 else "") + f"ground truth {matching}")
    from vslam.evaluation import check_gates  # here, not at the top: see vslam.cli

    _print_evaluation(evaluation, scale_source, backend_name, report, as_json,
                      check_gates(evaluation.rows, max_t_err, max_r_err, max_ate))


def _eval_batch(options: dict[str, Any]) -> None:
    """`--manifest` and `--merge` (vslam/cli/batch.py); the options of single runs are refused there."""
    from vslam.cli.batch import BatchOptions, Gates, eval_manifest, eval_merge
    from vslam_core.config import EngineConfig
    from vslam_core.config_file import load_config

    o = options
    per_log = {"--sequences": o["sequences"], "--frames": o["frames"], "--camera-height": o["camera_height"],
               "--trajectory": o["trajectory"], "--gt": o["gt"], "--intrinsics": o["intrinsics"], "--calib": o["calib"],
               "--topic": o["topic"], "--gt-topic": o["gt_topic"], "--gt-times": o["gt_times"], "--inject": o["inject"],
               "--format": o["trajectory_format"], "--json": o["as_json"] or None,
               "--gt-tolerance": o["time_tolerance"], "--gt-time-offset": o["gt_time_offset"],
               "--gt-rows": o["gt_rows"], "--time-offset": o["time_offset"]}
    for option in (name for name, value in per_log.items() if value is not None):
        fail(f"{option} does not apply to --manifest or --merge (give it per log, as a manifest column)")
    gates = Gates(o["max_t_err"], o["max_r_err"], o["max_ate"])
    report = o["report"]
    if o["merge"]:
        if o["manifest"] is not None:
            fail("give either --manifest or --merge, not both")
        extra = [Path(a) for a in ([o["source"]] if o["source"] is not None else []) + o["extra"]]
        eval_merge([*o["merge"], *extra], report, o["force"], gates)
        return
    if o["source"] is not None or o["extra"]:
        fail("--manifest names the sources: give no SOURCE")
    config = load_config(o["config_file"]) if o["config_file"] is not None else EngineConfig()
    config = config.with_scale(o["scale"].value)
    if o["backend"] is not None:
        config = config.with_backend(o["backend"].value)
    batch = BatchOptions(o["workers"], o["ray_address"], o["shard"], o["resume"], o["fail_fast"], o["force"])
    with report_writes(report):
        eval_manifest(o["manifest"], report, config, o["detail"], batch, gates, o["image_codec"])


def _check_report_dir(report: Path, force: bool) -> None:
    """Refuse a folder holding a report (without --force) or one another command is writing; hold it."""
    from vslam.common import lock_folder
    from vslam.evaluation import REPORT_FILES

    if report.exists() and not report.is_dir():
        fail(f"{report}: not a folder")
    lock_folder(report, "report folder")  # before the check: of two evals started at once, one writes
    existing = [name for name in REPORT_FILES if (report / name).exists()]
    if existing and not force:
        fail(f"{report}: holds a report already ({existing[0]}; use --force to replace it)")


def _print_evaluation(evaluation: Evaluation, scale: str, backend: str, report: Path | None, as_json: bool,
                      failures: list[str]) -> None:
    from vslam.common import markdown_table

    if as_json:
        data: dict[str, Any] = {"scale": scale, "backend": backend, **evaluation.as_json(),
                                "gates": {"passed": not failures, "failures": failures}}
        print(json.dumps(data, indent=2, allow_nan=False))
    else:
        rows = evaluation.rows + ([evaluation.mean] if len(evaluation.rows) > 1 else [])
        out.print(markdown_table([{k: v for k, v in r.items() if k != "alignment"} for r in rows]), highlight=False)
        if scale == "none":
            out.print("alignment   every number is of the Sim(3)-aligned estimate (--scale none: unit steps, no "
                      "metric scale)", highlight=False)
        if evaluation.matching is not None:
            out.print(evaluation.matching.describe(), highlight=False)
        elif len(evaluation.matchings) > 1:
            for name, matching in evaluation.matchings.items():
                out.print(f"{name}: {matching.describe()}", highlight=False)
        if evaluation.scored_trajectory is not None:
            from vslam.evaluation import scored_sentence

            out.print(f"scored      {scored_sentence(evaluation.scored_trajectory).removeprefix('Scored: ')}",
                      highlight=False, markup=False)
        if report is not None:
            out.print(f"report      {report / 'report.md'}", highlight=False)
    if evaluation.interrupted is not None:
        fail(f"interrupted by {evaluation.interrupted}; the report covers the frames processed",
             evaluation.interrupted.code)
    for message in failures:
        print_error(message, "gate failed:")
    if failures:
        raise typer.Exit(1)


