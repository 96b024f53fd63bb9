"""The `vslam` command line (thin: parse options, wire a source, the engine and a recorder)."""

from __future__ import annotations

import json
import sys
import uuid
from datetime import datetime
from enum import StrEnum
from pathlib import Path
from typing import Annotated, Any, NoReturn

import cv2
import numpy as np
import typer
from rich.console import Console

from app.compare import compare_recordings, format_differences
from app.crop import crop_recording, parse_crop_frames
from app.evaluation import REPORT_FILES, Evaluation, check_gates, evaluate_sources, evaluate_trajectory_file
from app.inspect import format_report, inspect_recording
from app.matching import DEFAULT_TOLERANCE_MS, MatchMode
from app.recording import Detail, version_properties
from app.report import json_ready, markdown_table, scored_estimate
from app.runner import record_run
from app.viewer import open_recording, snapshot
from vslam_core.config import EngineConfig, load_config
from vslam_core.errors import VslamError
from vslam_core.metrics import kitti_errors, paper_rms_error, scale_errors
from vslam_core.pipeline import RunResult
from vslam_core.scale import default_camera_height
from vslam_core.sources.base import FrameRange, FrameSource, describe_indices
from vslam_core.sources.open import open_source
from vslam_core.trajectory_io import write_kitti_poses, write_tum_poses

app = typer.Typer(
    name="vslam",
    help="Monocular visual odometry with every intermediate step recorded to Rerun.",
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_enable=False,
)
err = Console(stderr=True, soft_wrap=True)
out = Console(soft_wrap=True)
RECORDINGS = Path("recordings")


@app.callback()
def _root() -> None:
    """Monocular visual odometry with every intermediate step recorded to Rerun."""


class Scale(StrEnum):
    gt = "gt"
    none = "none"
    height = "height"


class Backend(StrEnum):
    vo = "vo"
    map = "map"


BACKEND_HELP = ("vo = frame-to-keyframe odometry; map = keyframes and landmarks, tracking against the map, windowed "
                "bundle adjustment, relocalisation [default: the config's backend, vo unless --config says otherwise]")
CAMERA_HEIGHT_HELP = ("metres from the camera to the road, for --scale height [default: the source's own: KITTI "
                      "1.65 m, the synthetic street's]")


class BadFrame(StrEnum):
    fail = "fail"
    skip = "skip"


class TrajectoryFormat(StrEnum):
    kitti = "kitti"
    tum = "tum"


def fail(message: str, code: int = 2) -> NoReturn:
    """One line on stderr, a non-zero exit, no traceback."""
    err.print(f"[bold red]error:[/] {message}", highlight=False, soft_wrap=True)
    raise typer.Exit(code)


def _check_new_file(path: Path, force: bool, what: str) -> None:
    if path.exists() and not force:
        fail(f"{path}: {what} exists already (use --force to replace it)")
    if path.exists() and path.is_dir():
        fail(f"{path}: is a folder, not a {what} file")
    _ensure_writable_folder(path.parent if str(path.parent) else Path("."), "output folder")


def _check_new_recording(path: Path, force: bool) -> None:
    if path.suffix != ".rrd":
        fail(f"{path}: a recording must end in .rrd")
    _check_new_file(path, force, "recording")


def _ensure_writable_folder(folder: Path, what: str) -> None:
    try:
        folder.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        fail(f"{folder}: cannot create {what} ({exc.strerror})")
    if not _writable(folder):
        fail(f"{folder}: {what} is not writable")


def _writable(folder: Path) -> bool:
    probe = folder / f".vslam-write-test-{uuid.uuid4().hex}"
    try:
        probe.touch()
        probe.unlink()
    except OSError:
        return False
    return True


def _default_output(source: FrameSource, frames: FrameRange) -> Path:
    selection = "" if str(frames) == ":" else "_" + str(frames).replace(":", "-")
    stamp = datetime.now().strftime("%Y%m%d-%H%M%S")
    return RECORDINGS / f"{source.name}{selection}_{stamp}.rrd"


def _recording_id(source: FrameSource, frames: FrameRange, config: EngineConfig) -> str:
    """Same input and config → same recording id, so two runs' files compare equal."""
    key = json.dumps([source.name, str(frames), len(source), config.to_dict()], sort_keys=True)
    return str(uuid.uuid5(uuid.NAMESPACE_URL, "vslam:" + key))


def _write_trajectory(path: Path, run: RunResult, fmt: TrajectoryFormat) -> None:
    if fmt is TrajectoryFormat.kitti:
        write_kitti_poses(path, run.pose_array())
    else:
        stamps = np.array([t if t is not None else float(i) for t, i in zip(run.timestamps, run.indices, strict=True)])
        write_tum_poses(path, stamps, run.pose_array())


def _summary(source: FrameSource, run: RunResult, config: EngineConfig) -> None:
    fps = run.frames / run.seconds if run.seconds > 0 else float("nan")
    lines = [
        f"frames      {run.frames} ({run.held} held the previous pose)",
        f"time        {run.seconds:.1f} s, {fps:.1f} frames/s",
        f"backend     {config.backend}",
        f"scale       {config.scale}"
        + (f" (camera {default_camera_height(source.camera_height, config):.2f} m above the road; no ground truth "
           "used)" if config.scale == "height" else ""),
    ]
    gt = source.ground_truth
    if gt is not None and run.frames > 1:
        gt = gt[: run.frames]
        if config.scale == "height":
            median, _, path = scale_errors(gt, run.pose_array())
            lines.append(f"step length {median:+.1f} % median error per frame, path length {path:+.1f} % vs ground "
                         "truth")
        scored = scored_estimate(gt, run.pose_array(), config.scale)  # --scale none: Sim(3)-aligned, as eval
        aligned = config.scale == "none"
        t_err, r_err = kitti_errors(gt, scored)
        lines.append(f"KITTI       t_err {t_err:.2f} %   r_err {r_err:.2f} °/100 m"
                     + ("   (path < 100 m: no segment)" if np.isnan(t_err) else "")
                     + ("   (after Sim(3) alignment: --scale none has unit steps)" if aligned else ""))
        lines.append(f"paper RMS   {paper_rms_error(gt, scored):.2f} m (x–z, "
                     + ("after Sim(3) alignment)" if aligned else "no alignment)"))
    out.print("\n".join(lines), highlight=False)


@app.command()
def run(
    source: Annotated[str | None, typer.Argument(help="KITTI root or sequence folder, image folder, video "
                                                 "file, or 'synthetic' (the default: no download)")] = None,
    sequence: Annotated[str | None, typer.Option("--sequence", "-s", help="KITTI sequence, e.g. 00")] = None,
    frames: Annotated[str | None, typer.Option(help="START:END[:STEP] of the source's frames (END excluded; an END "
                                               "past the last frame is clamped to it, like a Python slice)")]
    = None,
    scale: Annotated[Scale | None, typer.Option(help="translation length: gt = ground truth, height = from the "
                                                "known camera height over the road (no ground truth used), none "
                                                "= unit steps [default: gt when the source has ground truth]")]
    = None,
    camera_height: Annotated[float | None, typer.Option(min=0.01, help=CAMERA_HEIGHT_HELP)] = None,
    backend: Annotated[Backend | None, typer.Option(help=BACKEND_HELP)] = None,
    config_file: Annotated[Path | None, typer.Option("--config", help="engine config (TOML)")] = None,
    output: Annotated[Path | None, typer.Option("--output", "-o", help="recording (.rrd) to write "
                                                "[default: recordings/<source>_<time>.rrd]")] = None,
    detail: Annotated[Detail, typer.Option(help="full = every intermediate; standard = no 3-D points or per-track "
                                            "hover data; summary = no image or per-point data; off = no file")]
    = Detail.FULL,
    jpeg_quality: Annotated[int, typer.Option(min=1, max=100, help="JPEG quality of the recorded frames")] = 75,
    trajectory_out: Annotated[Path | None, typer.Option(help="write one pose per input frame here")] = None,
    trajectory_format: Annotated[TrajectoryFormat, typer.Option(help="kitti or tum")] = TrajectoryFormat.kitti,
    intrinsics: Annotated[str | None, typer.Option(help="fx,fy,cx,cy for image folders and videos")] = None,
    calib: Annotated[Path | None, typer.Option(help="KITTI-style calib file (P0 line) instead")] = None,
    gt: Annotated[Path | None, typer.Option(help="ground-truth poses (KITTI or TUM) for folders/videos")] = None,
    inject: Annotated[str | None, typer.Option(help="fault injection, e.g. dark@120,blur@200:210 (kinds: dark, "
                                               "overexposed, blur, frozen, drop, brightness, noise)")] = None,
    on_bad_frame: Annotated[BadFrame, typer.Option(help="an unreadable image: fail (stop, naming the file) or "
                                                   "skip (hold the pose, log an event)")] = BadFrame.fail,
    force: Annotated[bool, typer.Option("--force", help="replace existing output files")] = False,
) -> None:
    """Run the odometry on a source and write a Rerun recording (and optionally the trajectory)."""
    frame_range = FrameRange.parse(frames)
    config = load_config(config_file) if config_file is not None else EngineConfig()
    src = open_source(source, sequence=sequence, frames=frame_range, intrinsics=intrinsics, calib=calib,
                      ground_truth=gt, on_bad_frame=on_bad_frame.value, inject=inject)
    if scale is not None:
        config = config.with_scale(scale.value)
    elif config_file is None and src.ground_truth is None:
        config = config.with_scale("none")
    config = _with_camera_height(config, camera_height, src)
    if backend is not None:
        config = config.with_backend(backend.value)

    rrd = None if detail == Detail.OFF else (output or _default_output(src, frame_range))
    if rrd is not None:
        _check_new_recording(rrd, force)
    if trajectory_out is not None:
        _check_new_file(trajectory_out, force, "trajectory")

    selected = describe_indices(src.indices)  # the real range (`--frames` left out or clamped), e.g. 0:300
    properties = {
        "name": f"vslam {src.name} frames {selected} scale {config.scale}",
        "recording_id": _recording_id(src, frame_range, config),
        "source": src.name,
        "source_path": source or "synthetic",
        "frames": selected,
        "frame_count": str(len(src)),
        "scale": config.scale,
        "backend": config.backend,
        **({"inject": inject} if inject else {}),
        **version_properties(),
    }
    recorded = record_run(src, config, rrd, properties, err, detail, jpeg_quality)
    result, interrupted = recorded.result, recorded.interrupted
    if trajectory_out is not None and result.frames:
        _write_trajectory(trajectory_out, result, trajectory_format)
    if recorded.failure is not None:
        raise recorded.failure  # after the recording and the trajectory of the frames before it were saved

    _summary(src, result, config)
    if rrd is not None:
        out.print(f"recording   {rrd}", highlight=False)
    if trajectory_out is not None:
        out.print(f"trajectory  {trajectory_out} ({trajectory_format.value}, {result.frames} poses)", highlight=False)
    if interrupted is not None:
        last = result.indices[-1] if result.indices else None
        fail(f"interrupted by {interrupted} after {result.frames} frames"
             + (f" (last frame {last})" if last is not None else "") + "; outputs hold the frames processed",
             interrupted.code)


def _existing_recording(path: Path) -> Path:
    if not path.exists():
        fail(f"{path}: no such recording")
    if path.is_dir():
        fail(f"{path}: is a folder, not a .rrd recording")
    return path


@app.command()
def inspect(
    recording: Annotated[Path, typer.Argument(help="a .rrd written by vslam run")],
    as_json: Annotated[bool, typer.Option("--json", help="machine-readable output (keys documented in README)")]
    = False,
) -> None:
    """Summarise a recording without a viewer: properties, frames, stage timings, accuracy, flagged frames."""
    report = inspect_recording(_existing_recording(recording))
    if as_json:
        print(json.dumps(json_ready(report), indent=2, allow_nan=False))
    else:
        out.print(format_report(report), highlight=False)


@app.command(name="snapshot")
def snapshot_command(
    recording: Annotated[Path, typer.Argument(help="a .rrd written by vslam run")],
    frame: Annotated[int, typer.Option(help="frame to show (the source's frame index)")],
    out_dir: Annotated[Path, typer.Option("--out", help="folder for one PNG per view")],
) -> None:
    """Render every view of the recording's blueprint at one frame to PNG, with the real viewer, headless."""
    paths = snapshot(_existing_recording(recording), frame, out_dir)
    for path in paths:
        out.print(str(path), highlight=False)


@app.command(name="open")
def open_command(
    recording: Annotated[Path, typer.Argument(help="a .rrd written by vslam run")],
    web: Annotated[bool, typer.Option("--web", help="serve the web viewer on 127.0.0.1 instead")] = False,
    port: Annotated[int | None, typer.Option(help="web viewer port (default: a free one)")] = None,
) -> None:
    """Open a recording: the native viewer where a display exists, else the web viewer on 127.0.0.1."""
    open_recording(_existing_recording(recording), web=web, port=port)


@app.command()
def crop(
    recording: Annotated[Path, typer.Argument(help="a .rrd written by vslam run")],
    frames: Annotated[str, typer.Option(help="START:END of the frame timeline to keep (END excluded, either may be "
                                        "left out; clamped to the recording's frames like a Python slice; "
                                        "no STEP)")],
    output: Annotated[Path, typer.Option("--output", "-o", help="the cropped .rrd to write")],
    force: Annotated[bool, typer.Option("--force", help="replace an existing output")] = False,
) -> None:
    """Cut a recording down to the frames that matter (static data and blueprint kept)."""
    selection = parse_crop_frames(frames)
    _existing_recording(recording)
    _check_new_recording(output, force)
    summary = crop_recording(recording, selection, output)
    out.print(f"{output}: frames {summary.first_frame}..{summary.last_frame} ({summary.frame_count} frames), "
              f"{summary.output_bytes / 1e6:.1f} MB (from {summary.input_bytes / 1e6:.1f} MB)", highlight=False)


@app.command(name="eval")
def eval_command(
    source: Annotated[str | None, typer.Argument(help="KITTI root (with --sequences), sequence folder, image "
                                                 "folder with --gt, or 'synthetic'")] = None,
    sequences: Annotated[str | None, typer.Option(help="KITTI sequences, e.g. 00,05")] = None,
    frames: Annotated[str | None, typer.Option(help="START:END[:STEP] of every sequence (END excluded; an END past "
                                               "the last frame is clamped to it, like a Python slice)")] = None,
    scale: Annotated[Scale, typer.Option(help="gt: ground-truth step length; height: from the known camera "
                                         "height (no ground truth used); none: unit steps, scored after Sim(3) "
                                         "alignment")] = Scale.gt,
    camera_height: Annotated[float | None, typer.Option(min=0.01, help=CAMERA_HEIGHT_HELP)] = None,
    backend: Annotated[Backend | None, typer.Option(help=BACKEND_HELP)] = None,
    config_file: Annotated[Path | None, typer.Option("--config", help="engine config (TOML)")] = None,
    report: Annotated[Path | None, typer.Option(help="folder for metrics.csv/.parquet, report.md, trajectories, "
                                                "recordings and plots")] = None,
    detail: Annotated[Detail, typer.Option(help="detail of the recordings written to --report")] = Detail.FULL,
    trajectory: Annotated[Path | None, typer.Option(help="evaluate this trajectory file instead of running")] = None,
    gt: Annotated[Path | None, typer.Option(help="ground truth for --trajectory (or an image folder)")] = None,
    intrinsics: Annotated[str | None, typer.Option(help="fx,fy,cx,cy of an image folder or video SOURCE")] = None,
    calib: Annotated[Path | None, typer.Option(help="KITTI-style calib file (P0 line) of an image folder or video "
                                               "SOURCE, instead of --intrinsics")] = None,
    gt_times: Annotated[Path | None, typer.Option(help="timestamps of a KITTI --gt (the sequence's times.txt, "
                                                  "line i = pose row i): TUM rows are then matched by time")]
    = None,
    match: Annotated[MatchMode, typer.Option(help="--trajectory rows: auto = by timestamp when both sides have "
                                             "times, else row by row if the files have the same length; "
                                             "timestamps; rows = row i is frame i, whatever the lengths")]
    = MatchMode.auto,
    time_tolerance: Annotated[float, typer.Option(min=0.0, help="timestamp matching tolerance (ms)")]
    = DEFAULT_TOLERANCE_MS,
    trajectory_format: Annotated[TrajectoryFormat | None, typer.Option("--format", help="kitti or tum "
                                                                       "[default: from the columns]")] = None,
    as_json: Annotated[bool, typer.Option("--json", help="print the metrics as JSON (keys in README)")] = False,
    max_t_err: Annotated[float | None, typer.Option(help="gate: fail if any sequence's t_err (%) is above")] = None,
    max_r_err: Annotated[float | None, typer.Option(help="gate: fail if any r_err (°/100 m) is above")] = None,
    max_ate: Annotated[float | None, typer.Option(help="gate: fail if any ATE Sim(3) (m) is above")] = None,
    inject: Annotated[str | None, typer.Option(help="fault injection on every sequence (see vslam run)")] = None,
    on_bad_frame: Annotated[BadFrame, typer.Option(help="unreadable image: fail or skip")] = BadFrame.fail,
    force: Annotated[bool, typer.Option("--force", help="write into a --report folder that holds a report")]
    = False,
) -> None:
    """Score the engine (or any trajectory file) against ground truth; gates make it a CI check."""
    if report is not None:
        _check_report_dir(report, force)
    if trajectory is not None:
        if source is not None or sequences is not None:
            fail("give either SOURCE or --trajectory, not both")
        if gt is None:
            fail("--trajectory needs --gt (the ground-truth poses to compare with)")
        if backend is not None:
            fail("--backend chooses how the engine runs: it does not apply to --trajectory files")
        if intrinsics is not None or calib is not None:
            fail("--intrinsics and --calib describe the camera of a SOURCE: they do not apply to --trajectory files")
        fmt = trajectory_format.value if trajectory_format is not None else None
        evaluation = evaluate_trajectory_file(trajectory, gt, fmt, report,  # type: ignore[arg-type]
                                              gt_times, match, time_tolerance)
        scale_source = backend_name = "external"
    else:
        if gt_times is not None or match is not MatchMode.auto:
            fail("--gt-times and --match apply to --trajectory files only")
        config = load_config(config_file) if config_file is not None else EngineConfig()
        config = config.with_scale(scale.value)
        if backend is not None:
            config = config.with_backend(backend.value)
        frame_range = FrameRange.parse(frames)
        if sequences is not None:
            if source is None:
                fail("--sequences needs SOURCE, the KITTI dataset root")
            if intrinsics is not None or calib is not None:
                fail("--intrinsics and --calib are for image folders and videos: KITTI sequences have calib.txt")
            sources: list[FrameSource] = [
                open_source(source, sequence=s.strip(), frames=frame_range, on_bad_frame=on_bad_frame.value,
                            inject=inject)
                for s in sequences.split(",") if s.strip()
            ]
        else:
            sources = [open_source(source, frames=frame_range, intrinsics=intrinsics, calib=calib, ground_truth=gt,
                                   on_bad_frame=on_bad_frame.value, inject=inject)]
        for src in sources:
            config = _with_camera_height(config, camera_height, src)
        evaluation = evaluate_sources(sources, config, report, err, detail if report is not None else Detail.OFF,
                                      {"source_path": source or "synthetic", **({"inject": inject} if inject else {})})
        scale_source, backend_name = config.scale, config.backend
    _print_evaluation(evaluation, scale_source, backend_name, report, as_json,
                      check_gates(evaluation.rows, max_t_err, max_r_err, max_ate))


def _with_camera_height(config: EngineConfig, camera_height: float | None, source: FrameSource) -> EngineConfig:
    """`--camera-height` into the config, and a check (before anything runs) that `--scale height` knows
    the camera's height."""
    if camera_height is not None:
        if config.scale != "height":
            fail("--camera-height only applies with --scale height")
        config = config.with_camera_height(camera_height)
    if config.scale == "height":
        default_camera_height(source.camera_height, config)  # raises ConfigError naming --camera-height
    return config


def _check_report_dir(report: Path, force: bool) -> None:
    if report.exists() and not report.is_dir():
        fail(f"{report}: not a folder")
    existing = [name for name in REPORT_FILES if (report / name).exists()]
    if existing and not force:
        fail(f"{report}: holds a report already ({existing[0]}; use --force to replace it)")
    _ensure_writable_folder(report, "report folder")


def _print_evaluation(evaluation: Evaluation, scale: str, backend: str, report: Path | None, as_json: bool,
                      failures: list[str]) -> None:
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
        if report is not None:
            out.print(f"report      {report / 'report.md'}", highlight=False)
    if evaluation.interrupted is not None:
        fail(f"interrupted by {evaluation.interrupted}; the report covers the frames processed",
             evaluation.interrupted.code)
    for message in failures:
        err.print(f"[bold red]gate failed:[/] {message}", highlight=False)
    if failures:
        raise typer.Exit(1)


@app.command()
def compare(
    first: Annotated[Path, typer.Argument(metavar="A.rrd", help="the first run (e.g. before a change)")],
    second: Annotated[Path, typer.Argument(metavar="B.rrd", help="the second run (e.g. after it)")],
    output: Annotated[Path, typer.Option("--output", "-o", help="the side-by-side .rrd to write")],
    labels: Annotated[str, typer.Option(help="names of the two runs in legends, LABEL_A,LABEL_B")] = "A,B",
    force: Annotated[bool, typer.Option("--force", help="replace an existing output")] = False,
) -> None:
    """Put two runs side by side in one recording (overlaid metric plots) and print their differences."""
    names = [label.strip() for label in labels.split(",")]
    if len(names) != 2 or not all(names) or names[0] == names[1]:
        fail(f"--labels {labels!r}: give two different names, e.g. before,after")
    _existing_recording(first)
    _existing_recording(second)
    _check_new_recording(output, force)
    result = compare_recordings(first, second, output, (names[0], names[1]))
    out.print(format_differences(result), highlight=False)


def main() -> None:
    """Entry point: every `VslamError` becomes one line on stderr and exit code 2."""
    # OpenCV's own log lines (e.g. for a corrupt PNG) would precede our one-line error: we report it.
    cv2.utils.logging.setLogLevel(cv2.utils.logging.LOG_LEVEL_SILENT)
    try:
        app()
    except VslamError as exc:
        err.print(f"[bold red]error:[/] {exc}", highlight=False, soft_wrap=True)
        sys.exit(2)


if __name__ == "__main__":
    main()
