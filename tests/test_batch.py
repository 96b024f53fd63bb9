"""`vslam eval --manifest`: many logs serially, on local workers and as shards merged give identical rows; a
broken log fails alone; --resume, --fail-fast, manifest errors and merge refusals."""

from __future__ import annotations

import json
import os
import shutil
import signal
import subprocess
import sys
from pathlib import Path

import polars as pl
import pytest
from cli_helpers import vslam, vslam_here

from vslam.batch.manifest import LogSpec, shard
from vslam.batch.results import config_hash
from vslam_core.config import EngineConfig
from vslam_core.trajectory.io import read_kitti_poses, write_kitti_poses

ROOT = Path(__file__).resolve().parents[1]
NAMES = ["kitti-00-a", "kitti-00-b", "broken", "kitti-05-a", "kitti-05-b"]
WALL_CLOCK = ["fps", "elapsed_s"]


def broken_log(kitti_root: Path, folder: Path) -> None:
    """An image folder with a calib.txt and ground truth whose sixth image is truncated (fails at run time)."""
    images = folder / "images"
    images.mkdir(parents=True)
    sequence = kitti_root / "sequences" / "00"
    for index in range(5):
        shutil.copy(sequence / "image_0" / f"{index:06d}.png", images)
    (images / "000005.png").write_bytes((sequence / "image_0" / "000005.png").read_bytes()[:2000])
    shutil.copy(sequence / "calib.txt", folder / "calib.txt")
    write_kitti_poses(folder / "gt.txt", read_kitti_poses(kitti_root / "poses" / "00.txt", max_rows=6))


@pytest.fixture(scope="module")
def manifest(kitti_root: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    folder = tmp_path_factory.mktemp("batch")
    broken_log(kitti_root, folder / "broken")
    path = folder / "logs.csv"
    path.write_text(
        "name,source,sequence,frames,calib,gt,backend\n"
        f"kitti-00-a,{kitti_root},00,0:20,,,vo\n"
        f"kitti-00-b,{kitti_root},00,20:40,,,vo\n"
        "broken,broken/images,,,broken/calib.txt,broken/gt.txt,vo\n"  # relative to the manifest
        f"kitti-05-a,{kitti_root},05,0:20,,,vo\n"
        f"kitti-05-b,{kitti_root},05,20:40,,,map\n"  # the default engine, in every way of running a batch
    )
    return path


@pytest.fixture(scope="module")
def serial(manifest: Path) -> tuple[Path, subprocess.CompletedProcess[str]]:
    report = manifest.parent / "serial"
    return report, vslam("eval", "--manifest", manifest, "--report", report, "--workers", "1", "--detail", "summary")


def metric_rows(report: Path) -> str:
    """metrics.csv without the wall-clock columns, as text: equal text = bit-identical numbers."""
    return pl.read_csv(report / "metrics.csv").drop(WALL_CLOCK).write_csv()


@pytest.mark.kitti
def test_serial_batch_fails_the_broken_log_alone(serial: tuple[Path, subprocess.CompletedProcess[str]]) -> None:
    report, result = serial
    assert result.returncode == 1, result.stderr
    assert "Traceback" not in result.stderr
    table = pl.read_csv(report / "metrics.csv")
    assert table["sequence"].to_list() == [*NAMES, "mean"]  # manifest order
    failed = table.filter(pl.col("status") == "failed")
    assert failed["sequence"].to_list() == ["broken"]
    error = failed["error"][0]
    assert "000005.png" in error and "\n" not in error
    assert set(table.filter(pl.col("sequence") != "mean")["status"]) == {"ok", "failed"}
    assert table.filter(pl.col("sequence") == "mean")["frames"][0] == 80  # over the ok logs
    for name in ("kitti-00-a", "kitti-05-b"):
        assert (report / f"{name}.rrd").exists() and (report / f"{name}_top.png").exists()
        assert len(read_kitti_poses(report / f"{name}.txt")) == 20
    markdown = (report / "report.md").read_text()
    assert "### Failed logs" in markdown and "| broken |" in markdown
    lines = [line for line in result.stderr.splitlines() if line.startswith("[")]
    assert len(lines) == 5 and lines[2].startswith("[3/5] broken  FAILED ")
    assert "kitti-00-a  ok  t_err" in lines[0] and " fps " in lines[0] and "ETA" in lines[0]
    info = json.loads((report / "batch.json").read_text())
    assert info["config_hash"] == config_hash(EngineConfig()) and info["vslam_version"]


@pytest.mark.kitti
def test_workers_and_merged_shards_give_identical_rows(
        manifest: Path, serial: tuple[Path, subprocess.CompletedProcess[str]]) -> None:
    expected = metric_rows(serial[0])
    workers = manifest.parent / "workers"
    result = vslam("eval", "--manifest", manifest, "--report", workers, "--workers", "2", "--detail", "off")
    assert result.returncode == 1, result.stderr
    assert metric_rows(workers) == expected
    shards = [manifest.parent / f"shard{k}" for k in (1, 2)]
    for k, folder in enumerate(shards, start=1):
        result = vslam("eval", "--manifest", manifest, "--report", folder, "--shard", f"{k}/2", "--workers", "1",
                       "--detail", "summary")
        assert result.returncode == (1 if k == 1 else 0), result.stderr  # shard 1 has rows 0, 2 (broken), 4
    assert pl.read_csv(shards[0] / "metrics.csv")["sequence"].to_list() == ["kitti-00-a", "broken", "kitti-05-b",
                                                                          "mean"]
    merged = manifest.parent / "merged"
    result = vslam("eval", "--merge", *shards, "--report", merged)
    assert result.returncode == 1, result.stderr
    assert metric_rows(merged) == expected
    assert (merged / "kitti-05-a.rrd").exists() and (merged / "kitti-00-b.txt").exists()
    assert "| broken |" in (merged / "report.md").read_text()


@pytest.mark.kitti
@pytest.mark.ray
def test_a_ray_cluster_gives_identical_rows(manifest: Path, serial: tuple[Path, subprocess.CompletedProcess[str]],
                                            ray_cluster: str) -> None:
    """Each log a Ray task on a real cluster (started on 127.0.0.1 by the fixture): the same rows as serially,
    the broken log failed alone, exit 1."""
    report = manifest.parent / "ray"
    result = vslam("eval", "--manifest", manifest, "--report", report, "--detail", "summary",
                   env={"RAY_ADDRESS": ray_cluster})
    assert result.returncode == 1, result.stderr
    assert metric_rows(report) == metric_rows(serial[0])
    table = pl.read_csv(report / "metrics.csv")
    assert table.filter(pl.col("status") == "failed")["sequence"].to_list() == ["broken"]
    assert len([line for line in result.stderr.splitlines() if line.startswith("[")]) == 5
    assert (report / "kitti-05-b.rrd").exists() and "Traceback" not in result.stderr


@pytest.mark.kitti
def test_resume_runs_only_missing_changed_and_failed_logs(serial: tuple[Path, subprocess.CompletedProcess[str]],
                                                   manifest: Path) -> None:
    report = manifest.parent / "resumed"
    shutil.copytree(serial[0], report)
    (report / "logs" / "kitti-05-a.json").unlink()
    changed = manifest.parent / "changed.csv"  # kitti-00-b's row now selects other frames
    changed.write_text(manifest.read_text().replace(",00,20:40,", ",00,20:39,"))
    result = vslam("eval", "--manifest", changed, "--report", report, "--resume", "--workers", "1", "--detail",
                   "off")
    assert result.returncode == 1, result.stderr  # the broken log, run again, fails again
    lines = [line for line in result.stderr.splitlines() if line.startswith("[")]
    assert [line.split("  ")[0] for line in lines] == ["[1/3] kitti-00-b", "[2/3] broken", "[3/3] kitti-05-a"]
    table = pl.read_csv(report / "metrics.csv")
    assert table.filter(pl.col("sequence") == "kitti-00-b")["frames"][0] == 19
    unchanged = pl.col("sequence").is_in(["kitti-00-b", "mean"]).not_()
    expected = pl.read_csv(serial[0] / "metrics.csv").filter(unchanged).drop(WALL_CLOCK).write_csv()
    assert table.filter(unchanged).drop(WALL_CLOCK).write_csv() == expected


@pytest.mark.kitti
@pytest.mark.parametrize("workers", ["1", "2"])
def test_sigterm_keeps_the_finished_logs_and_exits_143(manifest: Path, workers: str) -> None:
    """A cancelled CI job: SIGTERM after the first log stops the batch (serially: the run notes the signal
    between frames; with workers: the parent stops them); the finished rows are written."""
    report = manifest.parent / f"terminated{workers}"
    environment = {**os.environ, "PYTHONPATH": os.pathsep.join([str(ROOT / "app"), str(ROOT)])}
    environment.pop("RAY_ADDRESS", None)
    process = subprocess.Popen([sys.executable, "-m", "vslam.cli", "eval", "--manifest", str(manifest), "--report",
                                str(report), "--workers", workers, "--detail", "off"], cwd=ROOT, env=environment,
                               stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    assert process.stderr is not None
    lines = [process.stderr.readline()]
    while not lines[-1].startswith("[1/5]"):  # the first finished log
        assert lines[-1], "".join(lines)
        lines.append(process.stderr.readline())
    process.send_signal(signal.SIGTERM)
    _, rest = process.communicate(timeout=120)
    assert process.returncode == 143, "".join(lines) + rest
    error = [line for line in rest.splitlines() if line.startswith("error:")]
    assert len(error) == 1 and error[0].startswith("error: interrupted by SIGTERM; the report covers the "), rest
    assert "Traceback" not in rest
    table = pl.read_csv(report / "metrics.csv")
    finished = table.filter(pl.col("sequence") != "mean")
    assert 1 <= len(finished) < 5 and set(finished["status"]) <= {"ok", "failed"}
    assert "**Interrupted**" in (report / "report.md").read_text()


@pytest.mark.kitti
def test_fail_fast_stops_at_the_first_failure(manifest: Path) -> None:
    report = manifest.parent / "fast"
    result = vslam("eval", "--manifest", manifest, "--report", report, "--workers", "1", "--fail-fast",
                   "--detail", "off")
    assert result.returncode == 1, result.stderr
    table = pl.read_csv(report / "metrics.csv")
    assert table["sequence"].to_list() == ["kitti-00-a", "kitti-00-b", "broken", "mean"]
    assert "Not run (--fail-fast stopped the batch): kitti-05-a, kitti-05-b." in (report / "report.md").read_text()


def assert_clean_error(result: subprocess.CompletedProcess[str], *fragments: str) -> None:
    assert result.returncode == 2, result.stderr
    lines = [line for line in result.stderr.splitlines() if line.strip()]
    assert len(lines) == 1 and lines[0].startswith("error: "), result.stderr
    for fragment in fragments:
        assert fragment in lines[0], lines[0]


@pytest.mark.parametrize(("body", "fragments"), [
    ("name,source,speed\na,synthetic,3\n", ("logs.csv header", "unknown column 'speed'")),
    ("name,source,frames\na,synthetic,0:10\nkitti-05-b,synthetic,10:x\n",
     ("logs.csv row 3 (name 'kitti-05-b')", "frames '10:x' is not START:END[:STEP]")),
    ("name,source\na,synthetic\nb,missing-folder\n", ("row 3 (name 'b')", "source 'missing-folder'")),
    ("name,source\na,synthetic\na,synthetic\n", ("row 3 (name 'a')", "duplicate name")),
    ("name,source,intrinsics\na,synthetic,\"1,2,3\"\n", ("row 2 (name 'a')", "intrinsics")),
])
def test_manifest_errors_name_the_row(tmp_path: Path, body: str, fragments: tuple[str, ...]) -> None:
    manifest = tmp_path / "logs.csv"
    manifest.write_text(body)
    result = vslam_here("eval", "--manifest", manifest, "--report", tmp_path / "report")
    assert_clean_error(result, *fragments)
    assert not (tmp_path / "report" / "batch.json").exists()  # nothing started


def test_bad_shard_and_missing_ray_are_one_line_errors(tmp_path: Path) -> None:
    manifest = tmp_path / "logs.toml"
    manifest.write_text('[[log]]\nname = "a"\nsource = "synthetic"\nframes = "0:10"\n')
    assert_clean_error(vslam_here("eval", "--manifest", manifest, "--report", tmp_path / "r", "--shard", "3/2"),
                       "--shard '3/2'")
    no_ray = tmp_path / "no_ray" / "ray"
    no_ray.mkdir(parents=True)
    (no_ray / "__init__.py").write_text("raise ImportError('ray is not installed')\n")
    result = vslam("eval", "--manifest", manifest, "--report", tmp_path / "r",
                   env={"PYTHONPATH": os.pathsep.join([str(no_ray.parent), str(ROOT / "app"), str(ROOT)]),
                        "RAY_ADDRESS": "10.0.0.1:6379"},
                   process=True)  # its own interpreter, where `import ray` finds the broken package first
    assert_clean_error(result, "--ray-address needs the cluster extra: pip install 'vslam[cluster]'")


def test_merge_refuses_different_configs(tmp_path: Path) -> None:
    manifest = tmp_path / "logs.csv"
    manifest.write_text("name,source,frames\na,synthetic,0:12\nb,synthetic,12:24\n")
    config = tmp_path / "fast.toml"
    config.write_text("[detector]\ntarget_tracks = 700\n")
    first, second = tmp_path / "s1", tmp_path / "s2"
    assert vslam("eval", "--manifest", manifest, "--report", first, "--shard", "1/2", "--detail", "off",
                 "--workers", "1").returncode == 0
    assert vslam("eval", "--manifest", manifest, "--report", second, "--shard", "2/2", "--detail", "off",
                 "--workers", "1", "--config", config).returncode == 0
    result = vslam("eval", "--merge", first, second, "--report", tmp_path / "merged")
    assert_clean_error(result, "different configs", str(first), str(second))
    assert_clean_error(vslam("eval", "--merge", first, first, "--report", tmp_path / "m2"), "in two reports")
    (tmp_path / "not-a-report").mkdir()
    assert_clean_error(vslam("eval", "--merge", first, tmp_path / "not-a-report", "--report", tmp_path / "m3"),
                       "no batch.json")


def test_shard_rule() -> None:
    specs = [LogSpec(i, f"log{i}", "synthetic") for i in range(7)]
    slices = [[s.index for s in shard(specs, k, 3)] for k in (1, 2, 3)]
    assert slices == [[0, 3, 6], [1, 4], [2, 5]]
