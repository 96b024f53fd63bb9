"""What `vslam compare` prints: one summary row per run, how each further run was made differently from the
first (the baseline), and every metric of every run with its difference from the baseline.

Every number comes from `vslam.rrd.inspect.inspect_recording` reports (keys as in ``vslam inspect --json``); a
run without some entity (no timing, no ground truth, e.g. a recording of an external trajectory) gets blank
cells (``–``), never an error.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Protocol

from vslam.compare.blueprint import run_prefixes
from vslam.compare.divergences import Divergence, describe_divergences
from vslam.compare.frames import FirstDivergence, describe_divergence
from vslam.recording import STAGES
from vslam.rrd import run_differences

#: Metrics shown as whole numbers by `format_differences`.
WHOLE_NUMBERS = ("frames.count", "frames.flagged", "bytes")
#: Summary columns: (key of `summary_row`, header, decimals).
SUMMARY_COLUMNS = (("frames", "frames", 0), ("t_err", "t_err %", 2), ("r_err", "r_err °/100 m", 2),
                   ("ate_sim3", "ATE Sim3 m", 3), ("paper_rms", "paper RMS m", 3), ("ms_per_frame", "ms/frame", 1),
                   ("fps", "fps", 1))


@dataclass(frozen=True)
class MetricDifference:
    """One metric of a run and the baseline: `a` (baseline), `b` (None where a run has no value) and B − A."""

    name: str
    a: float | None
    b: float | None

    @property
    def difference(self) -> float | None:
        if self.a is None or self.b is None:
            return None
        return self.b - self.a

    @property
    def percent(self) -> float | None:
        """(B − A) / |A| in %; None when A is missing, zero or not finite."""
        diff = self.difference
        if diff is None or self.a is None or not math.isfinite(self.a) or self.a == 0:
            return None
        return 100.0 * diff / abs(self.a)


class Compared(Protocol):
    """What the tables need of a comparison (`vslam.compare.comparison.ComparisonResult`)."""

    @property
    def output(self) -> Path: ...
    @property
    def output_bytes(self) -> int: ...
    @property
    def recording_name(self) -> str: ...
    @property
    def inputs(self) -> tuple[Path, ...]: ...
    @property
    def labels(self) -> tuple[str, ...]: ...
    @property
    def reports(self) -> tuple[dict[str, Any], ...]: ...
    @property
    def divergences(self) -> tuple[FirstDivergence | None, ...]: ...
    @property
    def thresholds(self) -> tuple[float, float]: ...
    @property
    def ranked(self) -> tuple[list[Divergence], ...]: ...
    @property
    def warnings(self) -> tuple[str, ...]: ...


# ------------------------------------------------------------------------------------------ summary


def summary_row(report: dict[str, Any]) -> dict[str, float | None]:
    """One run's headline numbers from its `inspect_recording` report: frames, KITTI t_err (%) and r_err
    (°/100 m), ATE after Sim(3) alignment and paper RMS (m) from the recording's verdict (``report_metrics``),
    the recorded stage times summed (ms/frame: the engine's time per frame, without start-up) and the frame
    rate that makes; None where the recording has no such value."""
    # a cropped file's verdict is of the whole run before crop (`report_metrics_cropped`): not this row's frames
    metrics = {} if report.get("report_metrics_cropped") else report.get("report_metrics") or {}
    stages = [stats["mean"] for stats in (report.get("stages_ms") or {}).values() if stats]
    ms = float(sum(stages)) if stages else None
    return {
        "frames": int(report["frames"]["count"]),
        "t_err": metrics.get("t_err"),
        "r_err": metrics.get("r_err"),
        "ate_sim3": metrics.get("ate_sim3"),
        "paper_rms": metrics.get("paper_rms", (report.get("accuracy") or {}).get("paper_rms_m")),
        "ms_per_frame": ms,
        "fps": 1000.0 / ms if ms else None,
    }


def format_summary(result: Compared) -> list[str]:
    """The per-run table: label, every `SUMMARY_COLUMNS` value, then `t_err` and ATE against the baseline."""
    rows = [summary_row(report) for report in result.reports]
    base = rows[0]
    header = ["run", *(title for _, title, _ in SUMMARY_COLUMNS), "Δt_err", "ΔATE", "file"]
    table = []
    for label, path, row in zip(result.labels, result.inputs, rows, strict=True):
        cells = [_fmt(row[key], digits) for key, _, digits in SUMMARY_COLUMNS]
        deltas = [_fmt(MetricDifference(key, base[key], row[key]).difference, digits, sign=True)
                  if row is not base else "" for key, digits in (("t_err", 2), ("ate_sim3", 3))]
        table.append([label, *cells, *deltas, str(path)])
    return _aligned([header, *table], left=(0, len(header) - 1))


def summary_markdown(name: str, labels: tuple[str, ...], inputs: tuple[Path, ...],
                     reports: tuple[dict[str, Any], ...]) -> str:
    """The comparison's ``/report``: its name, each run's label, prefix, input file and recording name, and
    the `summary_row` table (Markdown)."""
    keys = [key for key, _, _ in SUMMARY_COLUMNS]
    lines = [f"# {name}", "", "| run | prefix | file | recording |", "|---|---|---|---|"]
    lines += [f"| {label} | /{prefix} | {path.resolve()} | {report['recording_name']} |"
              for label, prefix, path, report in zip(labels, run_prefixes(len(labels)), inputs, reports, strict=True)]
    lines += ["", "| run | " + " | ".join(title for _, title, _ in SUMMARY_COLUMNS) + " |",
              "|---|" + "---|" * len(keys)]
    for label, report in zip(labels, reports, strict=True):
        row = summary_row(report)
        lines.append(f"| {label} | " + " | ".join(_fmt(row[key], digits) for key, _, digits in SUMMARY_COLUMNS)
                     + " |")
    return "\n".join(lines)


# -------------------------------------------------------------------------------------- differences


def metric_differences(report_a: dict[str, Any], report_b: dict[str, Any]) -> dict[str, MetricDifference]:
    """Frame count, flagged frames, file size, every stage and series mean, every accuracy value and every
    verdict metric of two `inspect_recording` reports (baseline, run), keyed like the report
    (``stages_ms.track.mean``, ``report_metrics.t_err``)."""
    reports = (report_a, report_b)
    rows: dict[str, list[Any]] = {
        "frames.count": [r["frames"]["count"] for r in reports],
        "frames.flagged": [sum(f["end"] - f["start"] + 1 for f in r["flagged"]) for r in reports],
        "bytes": [r["bytes"] for r in reports],
    }
    for section, names in (("stages_ms", STAGES), ("series", ())):
        for name in dict.fromkeys([*names, *report_a[section], *report_b[section]]):
            rows[f"{section}.{name}.mean"] = [((r[section] or {}).get(name) or {}).get("mean") for r in reports]
    for plot in dict.fromkeys([*(report_a.get("own_series") or {}), *(report_b.get("own_series") or {})]):
        own = [(r.get("own_series") or {}).get(plot) or {} for r in reports]
        for name in dict.fromkeys([*own[0], *own[1]]):  # a pipeline's own series (`vslam.log` scalars=)
            rows[f"own_series.{plot}.{name}.mean"] = [(series.get(name) or {}).get("mean") for series in own]
    for section in ("accuracy", "report_metrics"):
        for name in dict.fromkeys([*(report_a.get(section) or {}), *(report_b.get(section) or {})]):
            rows[f"{section}.{name}"] = [(r.get(section) or {}).get(name) for r in reports]
    return {key: MetricDifference(key, _number(a), _number(b)) for key, (a, b) in rows.items()}


def _number(value: Any) -> float | None:
    """A metric as a float; None where a run has none (absent, or NaN: e.g. no direction error without keyframes)."""
    return None if value is None or not math.isfinite(float(value)) else float(value)


def format_differences(result: Compared) -> str:
    """The comparison in plain text: the output, each run's file and name, the summary table, what differs
    in how each further run was made (properties and config, baseline → run), then the metric table
    (metric, each run's value, and for each further run X − baseline and %), columns aligned; each row shows
    about four significant digits of its larger value (counts and bytes as whole numbers)."""
    labels, reports = result.labels, result.reports
    base = labels[0]
    lines = [f"comparison  {result.output} ({result.output_bytes / 1e6:.1f} MB)",
             f"name        {result.recording_name}"]
    for label, path, report in zip(labels, result.inputs, reports, strict=True):
        lines.append(f"{label:<11} {path}: {report['recording_name']}")
    lines += ["", *format_summary(result), ""]
    lines += [f"warning     {warning}" for warning in result.warnings]
    for label, divergence, ranked in zip(labels[1:], result.divergences, result.ranked, strict=True):
        lines += describe_divergence(base, label, divergence, *result.thresholds)
        lines += describe_divergences(base, label, ranked)
    lines.append("")
    for label, report in zip(labels[1:], reports[1:], strict=True):
        # how the runs were made: properties and config, baseline → run (two runs: as before, unlabelled)
        made = run_differences(reports[0], report, (base, label))
        lines += made if len(labels) == 2 else [f"{label} vs {base}:", *(f"  {line}" for line in made)]
    versus = [metric_differences(reports[0], report) for report in reports[1:]]
    header = ["metric", *labels]
    for label in labels[1:]:
        header += [f"{label} − {base}", "%"]
    rows = []
    for name in dict.fromkeys(key for diffs in versus for key in diffs):
        values = [diffs.get(name) for diffs in versus]
        digits = _decimals(name, [v for d in values if d for v in (d.a, d.b)])
        baseline = next((d.a for d in values if d is not None and d.a is not None), None)
        row = [name, _fmt(baseline, digits), *(_fmt(d.b if d else None, digits) for d in values)]
        for d in values:
            row += [_fmt(d.difference if d else None, digits, sign=True),
                    "" if d is None or d.percent is None else f"{d.percent:+.1f}%"]
        rows.append(row)
    lines.append("")
    lines += _aligned([header, *rows], left=(0,))
    return "\n".join(lines)


def _aligned(rows: list[list[str]], left: tuple[int, ...]) -> list[str]:
    """Rows of cells as lines: the columns in `left` left-aligned, the others right-aligned."""
    widths = [max(len(row[i]) for row in rows) for i in range(len(rows[0]))]
    return ["  ".join(cell.ljust(width) if i in left else cell.rjust(width)
                      for i, (cell, width) in enumerate(zip(row, widths, strict=True))).rstrip() for row in rows]


def _decimals(name: str, values: list[float | None]) -> int:
    if name in WHOLE_NUMBERS:
        return 0
    finite = [abs(v) for v in values if v is not None and math.isfinite(v) and v != 0]
    if not finite:
        return 3
    return min(6, max(0, 3 - math.floor(math.log10(max(finite)))))


def _fmt(value: float | None, decimals: int, sign: bool = False) -> str:
    if value is None:
        return "–"
    if not math.isfinite(value):
        return str(value)
    return f"{value:{'+' if sign else ''},.{decimals}f}"


def comparison_json(result: Compared) -> dict[str, Any]:
    """``vslam compare --json``: the output, one entry per run (label, prefix, file, recording name and the
    `summary_row` values) and, per further run, every metric's baseline value, value, difference and %."""
    runs = [{"label": label, "prefix": prefix, "file": str(path), "recording_name": report["recording_name"],
             **summary_row(report)}
            for label, prefix, path, report in zip(result.labels, run_prefixes(len(result.labels)), result.inputs,
                                                   result.reports, strict=True)]
    versus = {label: {d.name: {"baseline": d.a, "value": d.b, "difference": d.difference, "percent": d.percent}
                      for d in metric_differences(result.reports[0], report).values()}
              for label, report in zip(result.labels[1:], result.reports[1:], strict=True)}
    divergence = {label: d.as_json() if d is not None else None
                  for label, d in zip(result.labels[1:], result.divergences, strict=True)}
    ranked = {label: [d.as_json() for d in items] for label, items in zip(result.labels[1:], result.ranked,
                                                                           strict=True)}
    rotation_deg, translation_pct = result.thresholds
    return {"output": str(result.output), "bytes": result.output_bytes, "recording_name": result.recording_name,
            "baseline": result.labels[0], "runs": runs, "differences": versus,
            # the second run against the first; `first_divergences` has every further run's
            "first_divergence": divergence[result.labels[1]], "first_divergences": divergence,
            # ranked {frame, rotation_deg, translation_pct, score, reasons_a, reasons_b}: the second run's, and
            # every further run's
            "divergences": ranked.get(result.labels[1], []), "divergences_by_run": ranked,
            "warnings": list(result.warnings),
            "divergence_thresholds": {"rotation_deg": rotation_deg, "translation_pct": translation_pct}}
