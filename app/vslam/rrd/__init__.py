"""Reading recordings back: the `.rrd` reader and the `rerun` CLI (`read`), a recording's run properties
(`provenance`), `vslam inspect` (`inspect`), `vslam crop` (`crop`, `crop_video`), `vslam repair` (`repair`) and
`vslam check` (`check`: any recording against the schema), suspect frames judged by the run itself (`suspects`).

The names other packages use are importable from here, loaded on first use (PEP 562).
"""

from typing import TYPE_CHECKING

from vslam_core.lazy import lazy_names

#: Where each public name lives.
_HOMES = {
    "RecordingError": "read",
    "blueprint_view_names": "read",
    "CameraPoses": "poses",
    "camera_poses": "poses",
    "check_recording": "check",
    "comparison_prefixes": "provenance",
    "crop_recording": "crop",
    "first_line": "read",
    "flatten": "provenance",
    "format_check": "check",
    "format_crop": "crop",
    "format_repair": "repair",
    "format_report": "inspect",
    "find_suspects": "suspects",
    "read_poses": "suspects",
    "robust_z": "suspects",
    "has_footer": "read",
    "inspect_recording": "inspect",
    "no_frames": "read",
    "open_store": "read",
    "parse_crop_frames": "crop",
    "read_entity": "read",
    "readable": "read",
    "repair_recording": "repair",
    "repaired_path": "repair",
    "rerun_binary": "read",
    "run_differences": "provenance",
    "run_rerun_cli": "read",
    "same_file": "read",
    "schema_contract": "check",
    "video_codecs": "crop_video",
    "work_dir_beside": "read",
}

if TYPE_CHECKING:
    from vslam.rrd.check import check_recording, format_check, schema_contract
    from vslam.rrd.crop import crop_recording, format_crop, parse_crop_frames
    from vslam.rrd.crop_video import video_codecs
    from vslam.rrd.inspect import format_report, inspect_recording
    from vslam.rrd.poses import CameraPoses, camera_poses
    from vslam.rrd.provenance import comparison_prefixes, flatten, run_differences
    from vslam.rrd.read import (
        RecordingError,
        blueprint_view_names,
        first_line,
        has_footer,
        no_frames,
        open_store,
        read_entity,
        readable,
        rerun_binary,
        run_rerun_cli,
        same_file,
        work_dir_beside,
    )
    from vslam.rrd.repair import format_repair, repair_recording, repaired_path
    from vslam.rrd.suspects import find_suspects, read_poses, robust_z


__getattr__ = lazy_names(__name__, _HOMES)


__all__ = [
    "CameraPoses",
    "RecordingError",
    "camera_poses",
    "blueprint_view_names",
    "check_recording",
    "comparison_prefixes",
    "crop_recording",
    "first_line",
    "flatten",
    "format_check",
    "format_crop",
    "format_repair",
    "format_report",
    "find_suspects",
    "has_footer",
    "inspect_recording",
    "no_frames",
    "open_store",
    "parse_crop_frames",
    "read_entity",
    "read_poses",
    "readable",
    "repair_recording",
    "repaired_path",
    "rerun_binary",
    "run_differences",
    "robust_z",
    "run_rerun_cli",
    "same_file",
    "schema_contract",
    "video_codecs",
    "work_dir_beside",
]
