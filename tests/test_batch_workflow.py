"""The example GitHub Actions workflow (docs/github-actions-shards.yml) runs as written: every shard job's and
the merge job's `run:` steps, in one folder where the downloaded artefacts would be, on a manifest of real KITTI
windows whose paths go through `$KITTI_ROOT` (the workflow's env)."""

from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path
from typing import Any

import polars as pl
import pytest
import yaml
from cli_helpers import vslam, vslam_here

ROOT = Path(__file__).resolve().parents[1]
WORKFLOW = ROOT / "docs" / "github-actions-shards.yml"


def _one_core() -> None:
    """In the step's process before it runs: only the first of the cores this process may use."""
    if hasattr(os, "sched_setaffinity"):
        os.sched_setaffinity(0, {min(os.sched_getaffinity(0))})


def run_steps(job: dict[str, Any], folder: Path, env: dict[str, str], matrix: dict[str, object]) -> list[int]:
    """Each `run:` step of `job` in bash (-e, as GitHub runs them) with `${{ matrix.X }}` filled in; the
    install step is skipped (this checkout is used). Returns the exit codes, stopping at the first failure
    unless the step runs `if: always()`.

    The steps run on one core: `--workers` then defaults to 1 and a shard runs its one log in its own process
    instead of starting a pool worker for it (~4 s of CPU per shard); what the workflow writes is the same
    either way (tests/test_batch.py: workers and shards give identical rows)."""
    codes: list[int] = []
    for step in job["steps"]:
        if "run" not in step or "pip install" in step["run"]:
            continue
        if codes and codes[-1] != 0 and step.get("if") != "always()":
            continue
        script = re.sub(r"\$\{\{\s*matrix\.(\w+)\s*\}\}", lambda m: str(matrix[m.group(1)]), step["run"])
        completed = subprocess.run(["bash", "-e", "-c", script], cwd=folder, env=env, capture_output=True,
                                   text=True, timeout=600, preexec_fn=_one_core)
        codes.append(completed.returncode)
        assert "Traceback" not in completed.stderr, completed.stderr
    return codes


def test_the_example_workflow_shards_and_merges(kitti_root: Path, tmp_path: Path) -> None:
    workflow = yaml.safe_load(WORKFLOW.read_text())
    shard_job, merge_job = workflow["jobs"]["shard"], workflow["jobs"]["merge"]
    shards = shard_job["strategy"]["matrix"]["shard"]
    command = next(s["run"] for s in shard_job["steps"] if "--shard" in s.get("run", ""))
    assert f"/{len(shards)} " in command  # the matrix and the /N of --shard agree
    assert merge_job["needs"] == "shard"

    # A `vslam` on PATH that is this checkout (the workflow installs it with pip).
    bin_folder = tmp_path / "bin"
    bin_folder.mkdir()
    (bin_folder / "vslam").write_text(f'#!/bin/sh\nexec "{sys.executable}" -m vslam.cli "$@"\n')
    (bin_folder / "vslam").chmod(0o755)
    summary = tmp_path / "summary.md"
    env = {**{k: v for k, v in os.environ.items() if k != "RAY_ADDRESS"}, **shard_job["env"],
           "KITTI_ROOT": str(kitti_root), "PATH": f"{bin_folder}{os.pathsep}{os.environ['PATH']}",
           "PYTHONPATH": os.pathsep.join([str(ROOT / "app"), str(ROOT)]), "GITHUB_STEP_SUMMARY": str(summary)}
    folder = tmp_path / "checkout"
    folder.mkdir()
    # Windows of KITTI 05 over 100 m (t_err exists; every second frame: 70 frames, 106-112 m) that pass the
    # workflow's gates with a wide margin (t_err 0.39-0.94 %, r_err 0.08-0.48 °/100 m): the merge job must pass.
    # Fewer logs than shards: the last shards' slices are empty, and the merge takes what the others wrote.
    windows = ("0:140:2", "150:290:2")
    # The odometry backend (`vo`): the subject is the workflow's sharding and merging, not the engine.
    rows = [f"kitti-05-{k},$KITTI_ROOT,05,{frames},vo" for k, frames in enumerate(windows)]
    (folder / "logs.csv").write_text("name,source,sequence,frames,backend\n" + "\n".join(rows) + "\n")

    for shard in shards:
        assert run_steps(shard_job, folder, env, {"shard": shard}) == [0], shard
    assert run_steps(merge_job, folder, env, {}) == [0, 0]

    merged = pl.read_csv(folder / "merged" / "metrics.csv")
    assert merged["sequence"].to_list()[:-1] == [row.split(",")[0] for row in rows]  # manifest order, from every shard
    assert set(merged["status"].to_list()[:-1]) == {"ok"}
    assert all((folder / f"shard-{shard}" / "batch.json").is_file() for shard in shards)  # empty ones too
    assert "kitti-05-1" in summary.read_text()  # the table went to the job summary


def test_an_unset_variable_in_a_manifest_path_is_named(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.delenv("VSLAM_TEST_UNSET", raising=False)
    manifest = tmp_path / "logs.csv"
    manifest.write_text("name,source,frames\na,${VSLAM_TEST_UNSET}/kitti,0:10\n")
    result = vslam_here("eval", "--manifest", manifest, "--report", tmp_path / "r")
    assert result.returncode == 2
    assert result.stderr.strip() == ("error: logs.csv row 2 (name 'a'): source '${VSLAM_TEST_UNSET}/kitti': "
                                     "environment variable VSLAM_TEST_UNSET is not set")


def test_home_and_variables_expand_in_every_path_column(kitti_root: Path, tmp_path: Path) -> None:
    sequence = kitti_root / "sequences" / "00"
    manifest = tmp_path / "logs.csv"
    manifest.write_text("name,source,frames,calib,gt\n"
                        "a,$SEQ/image_0,0:12,${SEQ}/calib.txt,~/poses.txt\n")
    home = tmp_path / "home"
    home.mkdir()
    # one pose per frame of the sample's 300 (with times.txt beside the images, another count is refused)
    poses = (kitti_root / "poses" / "00.txt").read_text().splitlines(keepends=True)
    (home / "poses.txt").write_text("".join(poses[:300]))
    result = vslam("eval", "--manifest", manifest, "--report", tmp_path / "r", "--workers", "1", "--detail", "off",
                   env={"SEQ": str(sequence), "HOME": str(home)})
    assert result.returncode == 0, result.stderr
    row = pl.read_csv(tmp_path / "r" / "metrics.csv").row(0, named=True)
    assert (row["sequence"], row["status"], row["frames"]) == ("a", "ok", 12)
    assert row["ate_se3"] is not None and row["ate_se3"] < 0.2  # scored against ~/poses.txt
