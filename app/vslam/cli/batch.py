"""`vslam eval --manifest LOGS.csv` and `vslam eval --merge DIR… --report OUT`: many logs, one report.

Exit codes: 0 all logs ok and every gate passed; 1 a log failed or a gate failed (report.md says which);
2 bad input (manifest, options, report folder), before any log runs; 130 Ctrl-C, 143 SIGTERM (finished logs
kept).
"""

from __future__ import annotations

import dataclasses
import importlib
import math
import os
import signal
import time
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import typer
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeRemainingColumn

from vslam.batch import (
    BATCH_FILE,
    BatchError,
    Executor,
    LogJob,
    LogResult,
    LogSpec,
    OnResult,
    Terminated,
    batch_info,
    batch_table,
    clear_log_results,
    config_hash,
    default_workers,
    eta_seconds,
    failed_log,
    forget_log_results,
    local_executor,
    merge_reports,
    parse_shard,
    read_batch_info,
    read_log_results,
    read_manifest,
    run_log,
    run_serial,
    shard,
    signals_noted,
    spec_hash,
    terminate_as_interrupt,
    write_batch_info,
    write_batch_report,
    write_log_result,
)
from vslam.cli.common import err, fail, out, print_error, warn
from vslam.common import lock_folder, markdown_table
from vslam.evaluation import REPORT_FILES, check_gates
from vslam.recording import Detail, ImageCodec
from vslam.runs import eta
from vslam_core.config import EngineConfig
from vslam_core.errors import VslamError

RAY_EXTRA = "--ray-address needs the cluster extra: pip install 'vslam[cluster]'"


@dataclass(frozen=True)
class Gates:
    max_t_err: float | None = None
    max_r_err: float | None = None
    max_ate: float | None = None


@dataclass(frozen=True)
class BatchOptions:
    workers: int | None = None
    ray_address: str | None = None
    shard: str | None = None
    resume: bool = False
    fail_fast: bool = False
    force: bool = False


def eval_manifest(manifest: Path, report: Path | None, config: EngineConfig, detail: Detail, options: BatchOptions,
                  gates: Gates, image_codec: ImageCodec = ImageCodec.JPEG) -> None:
    """Run every log of the manifest (or of its shard) into `report`, then write one report over them."""
    if report is None:
        fail("--manifest needs --report DIR (the folder for the batch's report and each log's files)")
    if options.workers is not None and options.ray_address is not None:
        if options.ray_address != os.environ.get("RAY_ADDRESS"):
            fail("give either --workers or --ray-address, not both")
        options = dataclasses.replace(options, ray_address=None)  # --workers wins over RAY_ADDRESS
    specs = read_manifest(manifest)
    selected = shard(specs, *parse_shard(options.shard)) if options.shard else specs
    if not selected:
        warn(f"--shard {options.shard}: no log of the manifest's {len(specs)} falls in this slice")
    executor = _executor(options, config)  # before any work: a missing Ray is a one-line error
    earlier = _prepare_report(report, config, options)
    done = _still_valid(earlier, selected)
    forget_log_results(report, set(earlier) - set(done))  # stale rows would reappear in a --merge
    write_batch_info(report, batch_info(config, manifest.resolve(), options.shard, [s.name for s in selected]))
    jobs = [LogJob(spec, config, report, detail, image_codec) for spec in selected if spec.name not in done]
    if done:
        err.print(f"resume: {len(done)} of {len(selected)} logs already in {report}, running {len(jobs)}",
                  highlight=False)
    results, interrupted = _run(jobs, executor, report, options.fail_fast)
    finished = {r.name for r in results} | set(done)
    not_run = [s.name for s in selected if s.name not in finished]
    notes = []
    if not_run:
        why = "interrupted" if interrupted else "--fail-fast stopped the batch"
        notes.append(f"Not run ({why}): {', '.join(not_run)}.")
    _finish(report, [*done.values(), *results], config, gates, notes, interrupted)


def eval_merge(folders: list[Path], report: Path | None, force: bool, gates: Gates) -> None:
    """Merge the reports of shards into `report`: one table over all their logs, in manifest order."""
    if report is None:
        fail("--merge needs --report OUT (the folder for the merged report)")
    if report.resolve() in {f.resolve() for f in folders}:
        fail(f"--report {report}: must not be one of the folders merged")
    for folder in folders:
        if not folder.is_dir():
            fail(f"--merge {folder}: no such folder")
    _lock(report, force)
    clear_log_results(report)
    results, config, info = merge_reports(folders, report)
    write_batch_info(report, info)
    _finish(report, results, config, gates, [f"Merged from {', '.join(map(str, folders))}."], None)


def _lock(report: Path, force: bool) -> None:
    """Hold the report folder; refuse one holding a report unless --force."""
    if report.exists() and not report.is_dir():
        fail(f"{report}: not a folder")
    lock_folder(report, "report folder")
    existing = [name for name in (*REPORT_FILES, BATCH_FILE) if (report / name).exists()]
    if existing and not force:
        fail(f"{report}: holds a report already ({existing[0]}; use --force to replace it, or --resume)")


def _prepare_report(report: Path, config: EngineConfig, options: BatchOptions) -> dict[str, LogResult]:
    """Lock the folder; with --resume, the logs it already finished ok (same config only), else a fresh start."""
    if not options.resume:
        _lock(report, options.force)
        clear_log_results(report)
        return {}
    _lock(report, True)
    if not (report / BATCH_FILE).exists():
        return {}
    info = read_batch_info(report)
    if info["config_hash"] != config_hash(config):
        raise BatchError(f"--resume {report}: its logs ran with another config (hash {info['config_hash']}, now "
                         f"{config_hash(config)})")
    # a failed log runs again: its cause may be gone (a file fixed, a worker lost); an engine failure recurs
    return {name: r for name, r in read_log_results(report).items() if r.status == "ok"}


def _still_valid(done: dict[str, LogResult], selected: list[LogSpec]) -> dict[str, LogResult]:
    """The finished logs --resume keeps: those still in the manifest (slice) with the same row, re-placed at
    the row's current position."""
    kept = {}
    for spec in selected:
        result = done.get(spec.name)
        if result is not None and result.spec_hash == spec_hash(spec):
            kept[spec.name] = dataclasses.replace(result, index=spec.index)
    return kept


def _executor(options: BatchOptions, config: EngineConfig) -> Executor:
    if options.ray_address is not None:
        return ray_executor(options.ray_address, config.threads)
    workers = options.workers if options.workers is not None else default_workers()
    return run_serial if workers <= 1 else local_executor(workers)


def ray_executor(address: str, num_cpus: int) -> Executor:
    """Each log a Ray task on the cluster at `address` (`vslam.batch.on_ray`); Ray is imported only here."""
    try:
        importlib.import_module("ray")
    except ImportError:
        raise VslamError(RAY_EXTRA) from None
    from vslam.batch import run_on_ray

    def execute(jobs: list[LogJob], on_result: OnResult, fail_fast: bool) -> None:
        run_on_ray(run_log, jobs, address, num_cpus, on_result, lambda result: result.status == "failed", fail_fast,
                   lambda job, error: failed_log(job, f"Ray task failed: {error}"))

    return execute


def _run(jobs: list[LogJob], executor: Executor, report: Path, fail_fast: bool
         ) -> tuple[list[LogResult], str | None]:
    """Run the jobs, keeping each finished log's result file and printing its line; (results, the signal that
    interrupted the batch: "SIGINT", "SIGTERM" or None)."""
    results: list[LogResult] = []
    interrupted: list[str] = []  # the signal that stopped a log (its run noted it: "interrupted by SIGTERM")
    start = time.monotonic()
    with _bar(len(jobs)) as advance:

        def on_result(_index: int, result: LogResult) -> None:
            if result.status == "interrupted":
                interrupted.append(result.error.split()[-1] if result.error else "SIGINT")
                return
            write_log_result(report, result)
            results.append(result)
            for warning in result.warnings:
                warn(f"{result.name}: {warning}")
            left = eta_seconds(time.monotonic() - start, len(results), len(jobs))
            err.print(progress_line(result, len(results), len(jobs), left), soft_wrap=True)
            advance()

        previous = signal.signal(signal.SIGTERM, terminate_as_interrupt)
        try:
            if jobs:
                executor(jobs, on_result, fail_fast)
        except KeyboardInterrupt as exc:
            return results, "SIGTERM" if isinstance(exc, Terminated) else "SIGINT"
        finally:
            signal.signal(signal.SIGTERM, previous)
    return results, interrupted[0] if interrupted else None


def progress_line(result: LogResult, done: int, total: int, left: float) -> str:
    """``[3/9] kitti-00-b  ok  t_err 1.23 %  31.2 fps  4.1 s  ETA 0:12`` (failed: ``FAILED <error>``)."""
    head = f"[{done}/{total}] {result.name}"
    tail = f"{result.elapsed_s:.1f} s" + (f"  ETA {eta(left)}" if done < total and left == left else "")
    if result.status != "ok" or result.row is None:
        return f"{head}  FAILED {result.error}  {tail}"
    t_err, fps = result.row.get("t_err", math.nan), result.row.get("fps", math.nan)
    t_text = "n/a" if t_err is None or math.isnan(t_err) else f"{t_err:.2f} %"
    return f"{head}  ok  t_err {t_text}  {fps:.1f} fps  {tail}"


@contextmanager
def _bar(total: int) -> Iterator[Any]:
    """A live bar of finished logs on a terminal (the lines print above it); nothing elsewhere."""
    if not err.is_terminal or total == 0:
        yield lambda: None
        return
    columns = (TextColumn("logs"), BarColumn(), MofNCompleteColumn(), TimeRemainingColumn())
    with Progress(*columns, console=err, transient=True) as bar:
        task = bar.add_task("logs", total=total)
        yield lambda: bar.advance(task)


def _finish(report: Path, results: list[LogResult], config: EngineConfig, gates: Gates, notes: list[str],
            interrupted: str | None) -> None:
    """Write the report, print its table, and exit: 128 + the signal when interrupted (130 Ctrl-C, 143
    SIGTERM), 1 a failed log or gate, else 0."""
    results = sorted(results, key=lambda r: r.index)
    ok = [r.row for r in results if r.status == "ok" and r.row is not None]
    failures = check_gates(ok, gates.max_t_err, gates.max_r_err, gates.max_ate)
    if interrupted:
        notes = [*notes, "**Interrupted**: the report covers the logs finished."]
    with signals_noted() as late:  # a stop while the report is written: written first, then exit
        if results:
            write_batch_report(report, results, config, failures, notes)
            rows, mean = batch_table(results)
            shown = [{k: v for k, v in row.items() if k not in ("alignment", "error", "elapsed_s")}
                     for row in rows + ([mean] if len(rows) > 1 else [])]
            out.print(markdown_table(shown), highlight=False)
            out.print(f"report      {report / 'report.md'}", highlight=False)
    interrupted = interrupted or (signal.Signals(late[0]).name if late else None)
    failed = [r for r in results if r.status != "ok"]
    if interrupted:
        fail(f"interrupted by {interrupted}; the report covers the {len(results)} logs finished",
             128 + signal.Signals[interrupted].value)
    for result in failed:
        print_error(f"{result.name}: {result.error}", "log failed:")
    for message in failures:
        print_error(message, "gate failed:")
    if failed or failures or any(note.startswith("Not run") for note in notes):
        raise typer.Exit(1)
