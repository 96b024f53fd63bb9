"""Other tools' log lines never reach the terminal around vslam's one-line error (issue 24, item 13): libpng's
``libpng error: …`` for a corrupt PNG, Rerun's coloured ``WARN re_log_encoding …`` for a recording of another
Rerun version, which gets vslam's own line saying which version wrote it."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
import rerun as rr
from cli_helpers import vslam

from vslam.rrd.read import RRD_MAGIC


@pytest.fixture(scope="module")
def recording(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A small .rrd written by this Rerun."""
    path = tmp_path_factory.mktemp("rrd") / "this.rrd"
    stream = rr.RecordingStream("vslam-test")
    stream.save(path)
    stream.set_time("frame", sequence=0)
    stream.log("/world/camera", rr.Transform3D(translation=[0.0, 0.0, 0.0]))
    stream.disconnect()
    return path


def _with_version(source: Path, target: Path, minor: int) -> Path:
    """`source` with its file header saying Rerun 0.`minor`.0 wrote it (bytes 4..7 after the magic)."""
    data = bytearray(source.read_bytes())
    assert data[:4] == RRD_MAGIC
    data[4:8] = bytes([0, minor, 0, 0])
    target.write_bytes(bytes(data))
    return target


@pytest.mark.parametrize(("minor", "words"), [(99, "newer than"), (24, "older than")])
def test_a_recording_of_another_rerun_gets_one_line_naming_the_version(recording: Path, tmp_path: Path, minor: int,
                                                                        words: str) -> None:
    other = _with_version(recording, tmp_path / "other.rrd", minor)
    for command in (["inspect", other], ["crop", other, "--frames", "0:1", "-o", tmp_path / "c.rrd"],
                    ["repair", other, "-o", tmp_path / "r.rrd"]):
        result = vslam(*command)
        assert result.returncode == 2, result.stderr
        assert result.stderr.startswith(f"error: {other}: written by Rerun 0.{minor}.0, {words} this vslam's Rerun")
        assert result.stderr.count("\n") == 1 and "WARN" not in result.stderr, result.stderr


def test_rerun_imported_after_vslam_is_quiet_and_leaves_no_rust_log(recording: Path, tmp_path: Path) -> None:
    """`import vslam` does not import rerun (vslam/__init__.py): rerun's Rust logger is quieted when anything
    first imports it, the variable gone again afterwards (the processes vslam starts log as usual). Reading a
    recording of another Rerun version through rerun's own reader then logs no coloured ``WARN``."""
    other = _with_version(recording, tmp_path / "other.rrd", 99)
    probe = ("import importlib.util, os, sys, vslam\nassert 'rerun' not in sys.modules and 'cv2' not in sys.modules\n"
             "importlib.util.find_spec('rerun')\n"  # a look-up alone (no import) does not spend the quieting
             "from rerun.chunk import RrdReader\nassert 'RUST_LOG' not in os.environ\n"
             f"try:\n    list(RrdReader({str(other)!r}).stream())\nexcept Exception:\n    pass\n")
    environment = {k: v for k, v in os.environ.items() if k != "RUST_LOG"}
    result = subprocess.run([sys.executable, "-W", "ignore", "-c", probe], capture_output=True, text=True,
                            env=environment, timeout=120)
    assert result.returncode == 0, result.stderr
    assert result.stderr == ""
    without_vslam = probe.replace("os, sys, vslam", "os, sys").replace("'rerun' not in sys.modules and ",
                                                                                     "")
    loud = subprocess.run([sys.executable, "-W", "ignore", "-c", without_vslam], capture_output=True, text=True,
                          env=environment, timeout=120)
    assert "WARN" in loud.stderr  # the check can fail: rerun itself would have logged


@pytest.mark.kitti
def test_a_corrupt_png_is_one_line_without_libpng(kitti_root: Path, tmp_path: Path) -> None:
    folder = tmp_path / "frames"
    folder.mkdir()
    for image in sorted((kitti_root / "sequences" / "00" / "image_0").iterdir())[:3]:
        shutil.copy(image, folder / image.name)
    broken = folder / "000001.png"
    data = bytearray(broken.read_bytes())
    data[len(data) // 2:len(data) // 2 + 100] = bytes(100)  # inside IDAT: its CRC no longer matches
    broken.write_bytes(bytes(data))
    result = vslam("run", folder, "--intrinsics", "718.856,718.856,607.1928,185.2157", "--detail", "off")
    assert result.returncode == 2
    lines = [line for line in result.stderr.splitlines() if not line.startswith("progress ")]
    assert lines == [f"error: {broken}: cannot read image (corrupt PNG: chunk IDAT at byte "
                     f"{lines[0].split('at byte ')[1].split()[0]} fails its CRC check)"], result.stderr
    assert "libpng" not in result.stderr
    skipped = vslam("run", folder, "--intrinsics", "718.856,718.856,607.1928,185.2157", "--detail", "off",
                    "--on-bad-frame", "skip")
    assert skipped.returncode == 0 and "libpng" not in skipped.stderr, skipped.stderr
