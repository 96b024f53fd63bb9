"""The report folder of a batch: per-log result files, ``batch.json``, the merged tables, and merging shards.

    DIR/batch.json          the config (as a dict), its hash, the vslam version, the manifest and the shard
    DIR/logs/<name>.json    one finished log (written atomically): what --resume skips and --merge reads
    DIR/<name>.rrd/.txt/_top.png   its recording, trajectory and top view
    DIR/metrics.csv/.parquet, report.md   the report `vslam eval` writes, plus status, error and elapsed_s

Rows are in manifest order whatever order the logs finished in; the mean is over the ``ok`` rows.
"""

from __future__ import annotations

import hashlib
import json
import os
import shutil
from pathlib import Path
from typing import Any

import vslam_core
from vslam.batch.run import LogResult
from vslam.common import COLUMNS, mean_row
from vslam.evaluation import Evaluation, write_report
from vslam_core.config import EngineConfig
from vslam_core.config_file import config_from_dict
from vslam_core.errors import VslamError

BATCH_FILE = "batch.json"
LOGS = "logs"
#: the files of one log beside the tables (a recording only with --detail other than off)
LOG_FILES = ("{}.rrd", "{}.txt", "{}_top.png")


class BatchError(VslamError):
    """A report folder that cannot be resumed or merged (one line)."""


def config_hash(config: EngineConfig) -> str:
    """A short hash of everything in the config that decides a trajectory (`threads` does not: tested)."""
    data = {k: v for k, v in config.to_dict().items() if k != "threads"}
    return hashlib.sha256(json.dumps(data, sort_keys=True).encode()).hexdigest()[:16]


def batch_info(config: EngineConfig, manifest: Path | None, shard: str | None, names: list[str]) -> dict[str, Any]:
    """The contents of ``batch.json``: what must match for shards to merge and a batch to resume."""
    return {"vslam_version": vslam_core.__version__, "config_hash": config_hash(config), "config": config.to_dict(),
            "manifest": str(manifest) if manifest is not None else None, "shard": shard, "logs": names}


def _write_atomic(path: Path, text: str) -> None:
    """Write `path` whole or not at all (a reader, or --resume after a crash, never sees half a file)."""
    temporary = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    temporary.write_text(text)
    os.replace(temporary, path)


def write_batch_info(report: Path, info: dict[str, Any]) -> None:
    _write_atomic(report / BATCH_FILE, json.dumps(info, indent=2) + "\n")


def read_batch_info(report: Path) -> dict[str, Any]:
    path = report / BATCH_FILE
    try:
        data = json.loads(path.read_text())
    except FileNotFoundError:
        raise BatchError(f"{report}: no {BATCH_FILE} (not the report folder of `vslam eval --manifest`)") from None
    except (OSError, ValueError) as exc:
        raise BatchError(f"{path}: unreadable ({exc})") from None
    if not isinstance(data, dict) or "config_hash" not in data:
        raise BatchError(f"{path}: not a batch description")
    return data


def write_log_result(report: Path, result: LogResult) -> None:
    """``logs/<name>.json`` of a finished log (NaN kept: the file is read back by vslam only)."""
    (report / LOGS).mkdir(exist_ok=True)
    _write_atomic(report / LOGS / f"{result.name}.json", json.dumps(result.as_json(), indent=1) + "\n")


def read_log_results(report: Path) -> dict[str, LogResult]:
    """Every finished log of a report folder, by name."""
    results = {}
    for path in sorted((report / LOGS).glob("*.json")):
        try:
            result = LogResult.from_json(json.loads(path.read_text()))
        except (OSError, ValueError, KeyError, TypeError) as exc:
            raise BatchError(f"{path}: unreadable log result ({exc}); delete it to run that log again") from None
        results[result.name] = result
    return results


def forget_log_results(report: Path, names: set[str]) -> None:
    """Delete the result files of these logs (rows --resume does not keep)."""
    for name in names:
        (report / LOGS / f"{name}.json").unlink(missing_ok=True)


def clear_log_results(report: Path) -> None:
    """Forget the finished logs of an earlier batch (a fresh run with --force)."""
    for path in (report / LOGS).glob("*.json"):
        path.unlink()


def report_rows(results: list[LogResult]) -> list[dict[str, Any]]:
    """One row per log with the same keys: the metrics, then status, error and elapsed_s (failed: no metrics)."""
    ok = [r.row for r in results if r.status == "ok" and r.row is not None]
    keys = [k for k in (ok[0] if ok else COLUMNS) if k != "sequence"]
    rows = []
    for result in results:
        values = result.row if result.status == "ok" and result.row is not None else {}
        rows.append({"sequence": result.name, **{k: values.get(k) for k in keys}, "status": result.status,
                     "error": result.error, "elapsed_s": result.elapsed_s})
    return rows


def batch_table(results: list[LogResult]) -> tuple[list[dict[str, Any]], dict[str, Any]]:
    """The rows of `results` in manifest order (`report_rows`) and their mean over the ok logs."""
    results = sorted(results, key=lambda r: r.index)
    rows = report_rows(results)
    ok_rows = [row for row, result in zip(rows, results, strict=True) if result.status == "ok"]
    mean = mean_row(ok_rows) if ok_rows else {"sequence": "mean"}
    mean = {**{k: None for k in rows[0]}, **mean, "status": "", "error": "",
            "elapsed_s": sum(r.elapsed_s for r in results)} if rows else mean
    return rows, mean


def write_batch_report(report: Path, results: list[LogResult], config: EngineConfig, gate_failures: list[str],
                       notes: list[str]) -> None:
    """metrics.csv/.parquet and report.md over `results` (sorted into manifest order here), then the batch's
    own section: which logs failed and why, which gates failed, what was not run."""
    results = sorted(results, key=lambda r: r.index)
    rows, mean = batch_table(results)
    by_length = {r.name: r.by_length for r in results if r.status == "ok" and r.by_length}
    write_report(report, Evaluation(rows, mean, by_length), config)
    failed = [r for r in results if r.status != "ok"]
    lines = ["", "## Batch", "",
             f"{len(results)} logs: {len(results) - len(failed)} ok, {len(failed)} failed. The mean is over the ok "
             "logs."]
    lines += [f"{note}" for note in notes]
    if failed:
        lines += ["", "### Failed logs", "", "| log | error |", "|---|---|"]
        lines += [f"| {r.name} | {r.error.replace('|', '/')} |" for r in failed]
    lines += ["", "### Gates", ""]
    lines += [f"- failed: {message}" for message in gate_failures] or ["All gates passed (of those given)."]
    with (report / "report.md").open("a") as handle:
        handle.write("\n".join(lines) + "\n")


def merge_reports(folders: list[Path], out: Path) -> tuple[list[LogResult], EngineConfig, dict[str, Any]]:
    """Check that the shard reports in `folders` are of one config and vslam version, then copy (or
    hard-link) each log's files and result into `out`. Returns the results (manifest order), the config
    and the merged ``batch.json``."""
    infos = [(folder, read_batch_info(folder)) for folder in folders]
    first_folder, first = infos[0]
    for folder, info in infos[1:]:
        for key, what in (("config_hash", "config"), ("vslam_version", "vslam version")):
            if info.get(key) != first.get(key):
                raise BatchError(f"cannot merge reports of different {what}s: {first_folder} has {first.get(key)}, "
                                 f"{folder} has {info.get(key)}")
    owner: dict[str, Path] = {}
    results: list[LogResult] = []
    for folder, _ in infos:
        for name, result in read_log_results(folder).items():
            if name in owner:
                raise BatchError(f"log {name!r} is in two reports: {owner[name]} and {folder}")
            owner[name] = folder
            results.append(result)
    (out / LOGS).mkdir(parents=True, exist_ok=True)
    for result in results:
        folder = owner[result.name]
        for pattern in LOG_FILES:
            _link_or_copy(folder / pattern.format(result.name), out / pattern.format(result.name))
        write_log_result(out, result)
    config = config_from_dict(first["config"])
    info = {**first, "shard": None, "merged_from": [str(f) for f in folders],
            "logs": [r.name for r in sorted(results, key=lambda r: r.index)]}
    return sorted(results, key=lambda r: r.index), config, info


def _link_or_copy(source: Path, target: Path) -> None:
    """Hard-link `source` to `target` (same file system), else copy it; a missing file is skipped."""
    if not source.exists():
        return
    target.unlink(missing_ok=True)
    try:
        os.link(source, target)
    except OSError:
        shutil.copy2(source, target)
