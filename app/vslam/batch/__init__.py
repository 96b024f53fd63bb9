"""Many logs at once (`vslam eval --manifest`): the manifest (`manifest`), one log's run and the executors
(`run`), local worker processes (`pool`), Ray tasks (`on_ray`), the result files and merging (`results`).

The names other packages use are importable from here, loaded on first use (PEP 562).
"""

from typing import TYPE_CHECKING

from vslam_core.lazy import lazy_names

#: Where each public name lives.
_HOMES = {
    "BATCH_FILE": "results",
    "BatchError": "results",
    "Executor": "run",
    "LogJob": "run",
    "LogResult": "run",
    "LogSpec": "manifest",
    "OnResult": "run",
    "Terminated": "run",
    "batch_info": "results",
    "batch_table": "results",
    "clear_log_results": "results",
    "config_hash": "results",
    "default_workers": "run",
    "eta_seconds": "run",
    "failed_log": "run",
    "forget_log_results": "results",
    "local_executor": "run",
    "merge_reports": "results",
    "parse_shard": "manifest",
    "read_batch_info": "results",
    "read_log_results": "results",
    "read_manifest": "manifest",
    "run_log": "run",
    "run_on_ray": "on_ray",
    "run_serial": "run",
    "shard": "manifest",
    "signals_noted": "pool",
    "spec_hash": "run",
    "terminate_as_interrupt": "run",
    "write_batch_info": "results",
    "write_batch_report": "results",
    "write_log_result": "results",
}

if TYPE_CHECKING:
    from vslam.batch.manifest import LogSpec, parse_shard, read_manifest, shard
    from vslam.batch.on_ray import run_on_ray
    from vslam.batch.pool import signals_noted
    from vslam.batch.results import (
        BATCH_FILE,
        BatchError,
        batch_info,
        batch_table,
        clear_log_results,
        config_hash,
        forget_log_results,
        merge_reports,
        read_batch_info,
        read_log_results,
        write_batch_info,
        write_batch_report,
        write_log_result,
    )
    from vslam.batch.run import (
        Executor,
        LogJob,
        LogResult,
        OnResult,
        Terminated,
        default_workers,
        eta_seconds,
        failed_log,
        local_executor,
        run_log,
        run_serial,
        spec_hash,
        terminate_as_interrupt,
    )


__getattr__ = lazy_names(__name__, _HOMES)


__all__ = [
    "BATCH_FILE",
    "BatchError",
    "Executor",
    "LogJob",
    "LogResult",
    "LogSpec",
    "OnResult",
    "Terminated",
    "batch_info",
    "batch_table",
    "clear_log_results",
    "config_hash",
    "default_workers",
    "eta_seconds",
    "failed_log",
    "forget_log_results",
    "local_executor",
    "merge_reports",
    "parse_shard",
    "read_batch_info",
    "read_log_results",
    "read_manifest",
    "run_log",
    "run_on_ray",
    "run_serial",
    "shard",
    "signals_noted",
    "spec_hash",
    "terminate_as_interrupt",
    "write_batch_info",
    "write_batch_report",
    "write_log_result",
]
