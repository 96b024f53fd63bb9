"""The `vslam` command line (thin: parse options, wire a source, the engine and a recorder)."""

from __future__ import annotations

import contextlib
import json
import sys
import uuid
from collections.abc import Iterator
from pathlib import Path
from typing import TYPE_CHECKING, Annotated

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
    Live,
    Scale,
    TrajectoryFormat,
    err,
    fail,
    live_default,
    out,
    print_error,
    refuse,
    warn,
)
from vslam.cli.entry import run as run_app
from vslam.cli.eval import eval_command
from vslam.compare import ROTATION_DEG as DIVERGE_DEG
from vslam.compare import TRANSLATION_PCT as DIVERGE_PCT
from vslam.recording import DEFAULT_DETAIL, HALF_SIZE_JPEG_QUALITY, JPEG_QUALITY, Detail, ImageCodec

if TYPE_CHECKING:
    from vslam.runs import RecordedRun, RunOutputs
    from vslam_core.config import EngineConfig
    from vslam_core.sources.base import FrameRange, FrameSource

# Each command imports what it needs when it runs: `vslam --help`, a usage error or a bad path answers
# without loading the engine, the recorder, polars and the viewer client (~0.4 s a start, ~300 in the tests).

app = typer.Typer(
    name="vslam",
    help="Monocular visual odometry with every intermediate step recorded to Rerun.",
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_enable=False,
    # plain help: shows every [default: …] (Rich took them for markup), no type hint on flags, no boxes
    rich_markup_mode=None,
    context_settings={"help_option_names": ["-h", "--help"]},
)

def _print_version(value: bool) -> None:
    if value:
        from vslam.recording import version_properties

        versions = version_properties()
        print(f"vslam {versions['vslam_version']} (OpenCV {versions['opencv_version']}, Rerun "
              f"{versions['rerun_version']}, Python {sys.version.split()[0]})")
        raise typer.Exit()


@app.callback()
def _root(
    version: Annotated[bool, typer.Option("--version", callback=_print_version, is_eager=True,
                                          help="print the versions of vslam, OpenCV, Rerun and Python, and exit")]
    = False,
) -> None:
    """Monocular visual odometry with every intermediate step recorded to Rerun."""


def _recording_path(path: Path) -> Path:
    if path.suffix != ".rrd":
        fail(f"{path}: a recording must end in .rrd")
    return path


def _recording_id(source: FrameSource, frames: FrameRange, config: EngineConfig) -> str:
    """Same input and config → same recording id, so two runs' files compare equal."""
    key = json.dumps([source.name, str(frames), len(source), config.to_dict()], sort_keys=True)
    return str(uuid.uuid5(uuid.NAMESPACE_URL, "vslam:" + key))


@app.command()
def run(
    source: Annotated[str | None, typer.Argument(help="KITTI root or sequence folder, ROS bag / MCAP "
                                                 "log, EuRoC, TUM monoVO or TUM RGB-D folder, image folder, "
                                                 "video file, or 'synthetic' (the default: no download)")] = None,
    sequence: Annotated[str | None, typer.Option("--sequence", "-s", help="KITTI sequence, e.g. 00")] = None,
    frames: Annotated[str | None, typer.Option(help="START:END[:STEP] of the source's frames (END excluded; an END "
                                               "past the last frame is clamped to it, like a Python slice)")]
    = None,
    scale: Annotated[Scale | None, typer.Option(help="translation length: gt = ground truth, height = from the "
                                                "known camera height over the road (no ground truth used), none "
                                                "= unit steps [default: gt when the source has ground truth]")]
    = None,
    camera_height: Annotated[float | None, typer.Option(help=CAMERA_HEIGHT_HELP)] = None,
    backend: Annotated[Backend | None, typer.Option(help=BACKEND_HELP)] = None,
    config_file: Annotated[Path | None, typer.Option("--config", help="engine config (TOML)")] = None,
    output: Annotated[Path | None, typer.Option("--output", "-o", help="recording (.rrd) to write "
                                                "[default: recordings/<source>_<frames>_<time>-<run id>.rrd]")]
    = None,
    detail: Annotated[Detail, typer.Option(help="full = every intermediate; standard = no 3-D points or per-track "
                                            "hover data; summary = no image or per-point data; off = no file "
                                            "(KITTI at 10 Hz, vo / map: standard 22 / 29 KB a frame, full 55 / 68, "
                                            "summary 4.4 / 7; docs/recordings.md)")]
    = DEFAULT_DETAIL,
    jpeg_quality: Annotated[int | None, typer.Option(
        min=1, max=100, show_default=False,
        help=f"JPEG quality of the recorded frames [default: {HALF_SIZE_JPEG_QUALITY} at standard, where they are "
             f"stored at half size; {JPEG_QUALITY} at full]")] = None,
    image_codec: Annotated[ImageCodec, typer.Option(help=IMAGE_CODEC_HELP)] = ImageCodec.JPEG,
    trajectory_out: Annotated[Path | None, typer.Option(help="write one pose per input frame here")] = None,
    trajectory_format: Annotated[TrajectoryFormat, typer.Option(help="kitti or tum")] = TrajectoryFormat.kitti,
    intrinsics: Annotated[str | None, typer.Option(help="fx,fy,cx,cy (a pinhole) for image folders, videos and logs")]
    = None,
    calib: Annotated[Path | None, typer.Option(help=CALIB_HELP)] = None,
    calib_scale: Annotated[float | None, typer.Option(min=0.01, max=100.0, help=CALIB_SCALE_HELP)] = None,
    gt: Annotated[Path | None, typer.Option(help=GT_HELP)] = None,
    topic: Annotated[str | None, typer.Option(help=TOPIC_HELP)] = None,
    gt_topic: Annotated[str | None, typer.Option(help=GT_TOPIC_HELP)] = None,
    gt_tolerance: Annotated[float | None, typer.Option(min=0.0, help=GT_TOLERANCE_HELP + " [default: 10]")] = None,
    gt_time_offset: Annotated[float | None, typer.Option(help=GT_TIME_OFFSET_HELP)] = None,
    gt_rows: Annotated[str | None, typer.Option(help=GT_ROWS_HELP)] = None,
    inject: Annotated[str | None, typer.Option(help="fault injection, e.g. dark@120,blur@200:210 (kinds: dark, "
                                               "overexposed, blur, frozen, drop, brightness, noise)")] = None,
    on_bad_frame: Annotated[BadFrame, typer.Option(help="an unreadable image: fail (stop, naming the file) or "
                                                   "skip (hold the pose, log an event)")] = BadFrame.fail,
    force: Annotated[bool, typer.Option("--force", help="replace existing output files (never one another run "
                                        "is writing)")] = False,
    route: Annotated[str | None, typer.Option(help="synthetic street's route: street (default), loop (around "
                                              "a block and back past the start, 660 frames), walk (a "
                                              "hand-held camera carried down the street, 30 Hz, 450 frames) or "
                                              "drive (lap after lap round two blocks at changing speeds, "
                                              "4541 frames)")] = None,
    save_map: Annotated[Path | None, typer.Option(help="save the map (the default backend's) into this new folder "
                                                  "after the run (Parquet tables + header.json)")] = None,
    prior_map: Annotated[Path | None, typer.Option("--map", help="localise each frame in this saved map (poses in "
                                                   "the map's frame; the map is not changed)")] = None,
    live: Annotated[Live | None, typer.Option(help="also show the run in a viewer while it goes on: native (a "
                                              "display), web (served on 127.0.0.1 like 'open --web'; kept until "
                                              "Ctrl-C), auto (= --live alone: native with a display, else web); "
                                              "the .rrd is written as without it")] = None,
    web_port: Annotated[int | None, typer.Option("--web-port", help="--live web: the web viewer (HTTP) port "
                                                 "(default: a free one)")] = None,
    grpc_port: Annotated[int | None, typer.Option("--grpc-port", help="--live: the viewer's gRPC port (default: "
                                                  "a free one)")] = None,
) -> None:
    """Run the odometry on a source and write a Rerun recording (and optionally the trajectory)."""
    from vslam.runs import (
        claim_run_outputs,
        input_warnings,
        output_problem,
        same_file_problem,
        with_camera_height,
    )
    from vslam_core.config import EngineConfig, describe_pixel_scale
    from vslam_core.config_file import load_config
    from vslam_core.sources.base import FrameRange, describe_indices, ground_truth_matching
    from vslam_core.sources.open import open_source

    if live is None and (web_port is not None or grpc_port is not None):
        fail("--web-port and --grpc-port are the live viewer's ports: add --live web")
    if live is not None and detail == Detail.OFF:
        fail("--live shows the recording while it is written: it needs one (not --detail off)")
    frame_range = FrameRange.parse(frames)
    config = load_config(config_file) if config_file is not None else EngineConfig()
    src = open_source(source, sequence=sequence, frames=frame_range, intrinsics=intrinsics, calib=calib,
                      ground_truth=gt, on_bad_frame=on_bad_frame.value, inject=inject, topic=topic, gt_topic=gt_topic,
                      gt_tolerance_s=None if gt_tolerance is None else gt_tolerance / 1000.0, route=route,
                      calib_scale=calib_scale, gt_time_offset_s=gt_time_offset, gt_rows=gt_rows)
    if scale is not None:
        config = config.with_scale(scale.value)
    elif config_file is None and src.ground_truth is None:
        config = config.with_scale("none")
    config = with_camera_height(config, camera_height, src)
    if backend is not None:
        config = config.with_backend(backend.value)
    from vslam.runs import map_saver, save_map_problem

    stored = None
    if prior_map is not None:
        from vslam_core.mapping.storage import load_map

        stored = load_map(prior_map, src.intrinsics)  # a MapFileError is one line
        config = config.with_backend("map").with_scale(stored.header.get("scale", config.scale))
    refuse(save_map_problem(save_map, prior_map, config))

    refuse(output_problem(output, detail == Detail.OFF))
    refuse(same_file_problem(output if detail != Detail.OFF else None, trajectory_out))
    for warning in input_warnings(src, config):
        warn(warning)

    selected = describe_indices(src.indices)  # the real range (`--frames` left out or clamped), e.g. 0:300
    recording = _recording_path(output) if output is not None and detail != Detail.OFF else None
    outputs = claim_run_outputs(recording, detail != Detail.OFF, src.name, selected, trajectory_out,
                                trajectory_format.value, force)
    rrd = outputs.recording.path if outputs.recording is not None else None
    from vslam.runs import record_run  # here: it loads the engine

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
        **({"prior_map": str(prior_map)} if prior_map is not None else {}),
        **({"gt_matching": matching} if (matching := ground_truth_matching(src)) else {}),
        **({"pixel_scale": scaled} if (scaled := describe_pixel_scale(config, src.intrinsics.width)) else {}),
    }
    if rrd is not None:  # the recording's (--detail off has none, and then never loads the recorder and rerun)
        from vslam.recording import version_properties

        properties.update(version_properties())
    with _live(live, rrd is not None, web_port, grpc_port) as live_url:
        try:
            recorded = record_run(src, config, rrd, properties, err, detail, jpeg_quality, outputs.trajectory,
                                  image_codec, stored, map_saver(save_map, src, config) if save_map else None,
                                  live_url)
        finally:
            outputs.release()
        # with --live web: before the viewer waits for Ctrl-C
        _report_run(src, recorded, config, outputs, prior_map is not None)


def _report_run(src: FrameSource, recorded: RecordedRun, config: EngineConfig, outputs: RunOutputs,
                in_map: bool = False) -> None:
    """The run's summary (`in_map`: poses in a prior map's frame) and where its outputs are; exit non-zero
    when it failed, was interrupted or tracked nothing."""
    from vslam.runs import EXIT_NOTHING_TRACKED, describe_outputs, nothing_tracked

    result, interrupted = recorded.result, recorded.interrupted
    if recorded.failure is None:
        from vslam.cli.summary import print_summary

        check = recorded.gt_check.summary() if recorded.gt_check is not None else None
        print_summary(src, result, config, in_map=in_map, gt_check=check)
        for warning in recorded.warnings():
            warn(warning)
    if where := describe_outputs(outputs, recorded.failure is not None):
        out.print(where, highlight=False)
    if recorded.failure is not None:
        raise recorded.failure  # after saying where the outputs (kept up to the failure) are
    if interrupted is not None:
        last = result.indices[-1] if result.indices else None
        fail(f"interrupted by {interrupted} after {result.frames} frames"
             + (f" (last frame {last})" if last is not None else "") + "; outputs hold the frames processed",
             interrupted.code)
    refuse(nothing_tracked(result), EXIT_NOTHING_TRACKED)


@contextlib.contextmanager
def _live(live: Live | None, recording: bool, web_port: int | None, grpc_port: int | None) -> Iterator[str | None]:
    """`vslam.viewer.live.live_viewer` for ``--live`` (its gRPC URL), else None; the ports only with --live."""
    if live is None:
        yield None
        return
    if not recording:
        fail("--live shows the recording while it is written: it needs one (not --detail off)")
    from vslam.viewer import live_viewer

    def say(line: str) -> None:
        out.print(line, highlight=False, markup=False)

    with live_viewer(str(live), web_port, grpc_port, say) as view:
        yield view.grpc_url


def _existing_recording(path: Path) -> Path:
    if not path.exists():
        fail(f"{path}: no such recording")
    if path.is_dir():
        fail(f"{path}: is a folder, not a .rrd recording")
    if not path.is_file():
        fail(f"{path}: not a file (a .rrd recording is a regular file)")
    return path


@app.command()
def inspect(
    recording: Annotated[Path, typer.Argument(help="a .rrd written by vslam run, or a map folder written by "
                                              "--save-map")],
    as_json: Annotated[bool, typer.Option("--json", help="machine-readable output (keys in docs/recordings.md)")]
    = False,
) -> None:
    """Summarise a recording without a viewer: properties, frames, stage timings, accuracy, flagged frames."""
    from vslam.common import json_ready
    from vslam.rrd import format_report, inspect_recording

    if recording.is_dir() and (recording / "header.json").is_file():  # a saved map (vslam run --save-map)
        from vslam.runs import format_map_summary, map_summary

        header = map_summary(recording)
        if as_json:
            print(json.dumps(header, indent=2))
        else:
            out.print(format_map_summary(recording, header), highlight=False, markup=False)
        return
    report = inspect_recording(_existing_recording(recording))
    if as_json:
        print(json.dumps(json_ready(report), indent=2, allow_nan=False))
    else:
        out.print(format_report(report), highlight=False)


@app.command(name="snapshot")
def snapshot_command(
    recording: Annotated[Path, typer.Argument(help="a .rrd written by vslam run")],
    frame: Annotated[str, typer.Option(help="frame to show: the source's frame index, or 'last'")],
    out_dir: Annotated[Path, typer.Option("--out", help="folder for one PNG per view")],
    size: Annotated[str, typer.Option(help="viewer window WIDTHxHEIGHT: each view's PNG is about this large")]
    = "1280x720",  # vslam.viewer.headless.DEFAULT_SIZE (a test keeps the two equal)
    view: Annotated[list[str] | None, typer.Option(
        metavar="<str>", help="only this view's picture (its name or file name, 'all' for the whole layout); repeat "
                              "for more")] = None,
) -> None:
    """Render every view of the recording's blueprint at one frame to PNG, with the real viewer, headless."""
    from vslam.rrd import schema_contract
    from vslam.viewer import parse_frame, parse_size, snapshot

    window = parse_size(size)
    recording = _existing_recording(recording)  # before the contract: its own one line, said once
    try:
        with schema_contract(recording):  # a recording `vslam check` rejects: one line, never a traceback
            paths = snapshot(recording, parse_frame(frame), out_dir, window_size=window, only=view or ())
    except KeyboardInterrupt:
        fail(f"snapshot interrupted: no picture written to {out_dir}", 130)
    for path in paths:
        out.print(str(path), highlight=False)


@app.command(name="open")
def open_command(
    recording: Annotated[Path, typer.Argument(help="a .rrd written by vslam run")],
    web: Annotated[bool, typer.Option("--web", help="serve the web viewer on 127.0.0.1 instead")] = False,
    web_port: Annotated[int | None, typer.Option("--web-port", "--port",
                                                 help="web viewer (HTTP) port (default: a free one)")] = None,
    grpc_port: Annotated[int | None, typer.Option("--grpc-port",
                                                  help="gRPC port the page loads the data from (default: a free "
                                                       "one); fix both to set up an SSH tunnel in advance")]
    = None,
) -> None:
    """Open a recording: the native viewer where a display exists, else the web viewer on 127.0.0.1."""
    from vslam.rrd import schema_contract
    from vslam.viewer import open_recording, port_problem

    refuse(port_problem(web_port, "--web-port"))
    refuse(port_problem(grpc_port, "--grpc-port"))
    recording = _existing_recording(recording)  # before the contract: its own one line, said once
    with schema_contract(recording):  # a recording `vslam check` rejects: one line, never a traceback
        open_recording(recording, web=web, web_port=web_port, grpc_port=grpc_port)


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
    from vslam.common import claimed
    from vslam.rrd import crop_recording, format_crop, parse_crop_frames

    selection = parse_crop_frames(frames)
    _existing_recording(recording)
    with claimed(_recording_path(output), force, "recording"):
        summary = crop_recording(recording, selection, output)
    out.print(format_crop(summary, recording))


# extra arguments: the folders after `--merge DIR` (`--merge A B C`); refused by every other form of eval
app.command(name="eval", context_settings={"allow_extra_args": True})(eval_command)  # vslam/cli/eval.py


@app.command()
def compare(
    recordings: Annotated[list[Path], typer.Argument(metavar="A.rrd B.rrd [C.rrd …]",
                                                     help="two or more runs; the first is the baseline the "
                                                     "others are compared with (e.g. before a change)")],
    output: Annotated[Path, typer.Option("--output", "-o", help="the side-by-side .rrd to write")],
    labels: Annotated[str | None, typer.Option(help="names of the runs in legends and tables, one per "
                                               "recording, comma-separated, e.g. before,after [default: A,B,C…]")]
    = None,
    force: Annotated[bool, typer.Option("--force", help="replace an existing output, and compare runs of different "
                                        "sources or without a common frame (refused otherwise)")] = False,
    as_json: Annotated[bool, typer.Option("--json", help="machine-readable output (keys in docs/recordings.md)")]
    = False,
    diverge_deg: Annotated[float, typer.Option(min=0.0, help="first divergence: a frame whose step rotation "
                                               "differs from the first run's by more than this (degrees)")]
    = DIVERGE_DEG,
    diverge_pct: Annotated[float, typer.Option(min=0.0, help="… or whose step translation differs by more than "
                                               "this % of the first run's step")] = DIVERGE_PCT,
) -> None:
    """Put two or more runs side by side in one recording (overlaid metric plots and per-frame differences),
    print one summary row per run, every difference from the first run, and the first frame where each run
    diverges from the first."""
    from vslam.common import claimed, json_ready
    from vslam.compare import (
        PREFIXES,
        check_labels,
        compare_recordings,
        comparison_json,
        default_labels,
        format_differences,
    )

    if len(recordings) < 2:
        fail(f"give two or more recordings to compare, got {len(recordings)}")
    if len(recordings) > len(PREFIXES):
        fail(f"at most {len(PREFIXES)} recordings can be compared, got {len(recordings)}")
    names = ([label.strip() for label in labels.split(",")] if labels is not None
             else list(default_labels(len(recordings))))
    if problem := check_labels(names, len(recordings)):
        fail(f"--labels {labels!r}: {problem}")
    for recording in recordings:
        _existing_recording(recording)
    with claimed(_recording_path(output), force, "recording"):
        result = compare_recordings(*recordings, output, labels=names, rotation_deg=diverge_deg,
                                    translation_pct=diverge_pct, force=force)
    if as_json:
        print(json.dumps(json_ready(comparison_json(result)), indent=2, allow_nan=False))
    else:
        out.print(format_differences(result), highlight=False)


@app.command()
def repair(
    recording: Annotated[Path, typer.Argument(help="a .rrd cut short (killed run, full disk) or any recording")],
    output: Annotated[Path | None, typer.Option("--output", "-o", help="the finalised .rrd to write "
                                                "[default: <name>.repaired.rrd beside it]")] = None,
    force: Annotated[bool, typer.Option("--force", help="replace an existing output")] = False,
) -> None:
    """Finalise a recording cut short (no footer: the run was killed, crashed or ran out of disk) into a
    complete copy holding every frame it recorded."""
    from vslam.common import claimed
    from vslam.rrd import format_repair, repair_recording, repaired_path

    target = _recording_path(output or repaired_path(_existing_recording(recording)))
    with claimed(target, force, "recording"):
        summary = repair_recording(recording, target)
    out.print(format_repair(summary), highlight=False)


@app.command()
def check(
    recording: Annotated[Path, typer.Argument(help="any .rrd: vslam's, the logging API's (vslam.log), or one "
                                              "written with the Rerun SDK")],
) -> None:
    """Validate a recording against the recording schema (docs/recording-schema.md): one line per missing or
    malformed entity, component or property, with the commands it affects. Exit 0 only when it conforms."""
    from vslam.rrd import check_recording, format_check

    result = check_recording(_existing_recording(recording))
    for line in format_check(result):
        print(line)
    if not result.conforms:
        raise typer.Exit(1)


def main() -> None:
    """Entry point: every `VslamError` and usage error becomes one line on stderr and exit code 2."""
    sys.argv[1:] = live_default(sys.argv[1:])
    run_app(app, print_error)


if __name__ == "__main__":
    main()
