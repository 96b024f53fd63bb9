"""The files one run writes (`RunOutputs`), claimed before it starts (`claim_run_outputs`, `vslam.common.outputs`)
and described after it ends (`describe_outputs`). Apart from the runner, so that a run refused at once (an output
that exists) never loads the engine or the recorder."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from vslam.common import ClaimedFile, OutputError, claim, default_recording
from vslam.runs.trajectory_out import Format, TrajectoryWriter


@dataclass
class RunOutputs:
    """The files one run writes, claimed for it alone (see `vslam.common.outputs`)."""

    recording: ClaimedFile | None
    trajectory_file: ClaimedFile | None
    trajectory: TrajectoryWriter | None

    def release(self) -> None:
        for claimed in (self.recording, self.trajectory_file):
            if claimed is not None:
                claimed.release(keep=claimed is self.recording or bool(self.trajectory and self.trajectory.lines))


def claim_run_outputs(output: Path | None, record: bool, source_name: str, frames: str, trajectory: Path | None,
                      trajectory_format: Format, force: bool) -> RunOutputs:
    """Claim the recording (`output`, or a fresh default name when `record`) and the trajectory file before
    the run starts; `OutputError` in one line if one is taken."""
    recording: ClaimedFile | None = None
    if output is not None:
        recording = claim(output, force, "recording")
    elif record:
        for attempt in range(3):  # a default name is new by construction; a clash means another id
            try:
                recording = claim(default_recording(source_name, frames), False, "recording")
                break
            except OutputError:
                if attempt == 2:
                    raise
    if trajectory is None:
        return RunOutputs(recording, None, None)
    try:
        trajectory_file = claim(trajectory, force, "trajectory")
    except OutputError:
        if recording is not None:
            recording.release(keep=False)
        raise
    return RunOutputs(recording, trajectory_file, TrajectoryWriter(trajectory_file, trajectory_format))


def describe_outputs(outputs: RunOutputs, failed: bool) -> str:
    """Where the outputs are (also, and above all, after a failure): one line each."""
    lines = []
    if outputs.recording is not None:
        from vslam.common import has_footer  # here: it loads rerun

        path = outputs.recording.path
        complete = has_footer(path)
        lines.append(f"recording   {path}" + ("" if complete else
                                              f" (cut short: finalise with `vslam repair {path}`)"))
    if outputs.trajectory is not None and outputs.trajectory_file is not None:
        writer = outputs.trajectory
        if writer.lines or not failed:
            lines.append(f"trajectory  {writer.path} ({writer.format}, {writer.lines} poses)")
    return "\n".join(lines)
