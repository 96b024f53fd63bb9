"""The CLI answers `--help`, usage errors and bad paths without loading the engine, the recorder, polars
or the viewer client: each command imports what it needs when it runs (vslam/cli/commands.py)."""

from __future__ import annotations

import inspect
import subprocess
import sys
from pathlib import Path

import vslam.cli.commands
from vslam.viewer.headless import DEFAULT_SIZE

ROOT = Path(__file__).resolve().parents[1]
HEAVY = ("polars", "av", "gtsam", "ray", "rosbags", "vslam_core.engine", "vslam.recording.recorder",
         "vslam.evaluation.evaluate", "vslam.viewer.headless", "vslam.batch.run", "vslam_core.sources.kitti", "rerun",
         "cv2", "yaml", "pyarrow")


def test_importing_the_cli_loads_none_of_the_heavy_modules() -> None:
    probe = f"import sys, vslam.cli.commands; print(','.join(m for m in {HEAVY!r} if m in sys.modules))"
    result = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True, cwd=ROOT, timeout=120)
    assert result.returncode == 0, result.stderr
    assert result.stdout.strip() == ""


def test_a_run_refused_at_once_loads_neither_the_engine_nor_the_recorder(kitti_root: Path, tmp_path: Path) -> None:
    """An output that exists is refused after the source is opened: the engine, the recorder, rerun and polars
    are not loaded for that (each is ~0.3-1 s of CPU a process)."""
    taken = tmp_path / "taken.rrd"
    taken.write_bytes(b"")
    probe = ("import sys\nfrom vslam.cli import main\n"
             f"sys.argv = ['vslam', 'run', {str(kitti_root)!r}, '-s', '05', '--frames', '0:10', '-o', {str(taken)!r}]\n"
             "try:\n    main()\nexcept SystemExit as exc:\n    print(exc.code)\n"
             f"print(','.join(m for m in {HEAVY!r} + ('vslam_core.pipeline', 'pandas') if m in sys.modules))")
    result = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True, cwd=ROOT, timeout=120)
    assert result.stderr.startswith(f"error: {taken}: recording exists already"), result.stderr
    code, loaded = result.stdout.splitlines()
    assert code == "2"
    assert set(loaded.split(",")) - {""} <= {"cv2", "vslam_core.sources.kitti"}


def test_the_snapshot_size_default_is_the_snapshot_modules() -> None:
    default = inspect.signature(vslam.cli.commands.snapshot_command).parameters["size"].default
    assert default == f"{DEFAULT_SIZE[0]}x{DEFAULT_SIZE[1]}"
