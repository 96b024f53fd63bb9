"""The development matrix's rows as a table, a CSV and a comparison against a saved CSV (benchmarks/matrix.py).

One row per run (a dict with the keys of `FIELDS`); a *group* is (family, backend, scale), e.g. ("KITTI step 2",
"map", "none"). Per group the table prints a mean row (over every run of the group that did not fail) and its
worst run (the largest ATE after Sim(3)), and the group's noise: the sample standard deviation over RANSAC seeds
of the group's mean (each seed's runs averaged first), the spread a change must beat to count.
"""

from __future__ import annotations

import csv
import math
from collections.abc import Iterable
from pathlib import Path

import numpy as np

Row = dict[str, object]

#: The CSV's columns, in order. ate: without alignment (n/a with --scale none: unit steps); t_err: KITTI devkit
#: after Sim(3) with --scale none (n/a on paths under 100 m); rotation_deg: the final frame's rotation error
#: relative to the first; held: frames whose pose was not tracked (coasted: of those, dead-reckoned); placed_*:
#: the map backend's tracking mode per frame (vo: empty).
FIELDS = ("family", "case", "backend", "scale", "seed", "frames", "error", "ate_sim3", "ate", "t_err",
          "rotation_deg", "held", "coasted", "placed_map", "placed_two_view", "placed_relocalised",
          "placed_coasted", "placed_init", "placed_lost", "seconds")
#: Metrics averaged per group and compared (larger is worse for every one).
METRICS = ("ate_sim3", "ate", "t_err", "rotation_deg", "held_pct")
#: A group is worse beyond its noise when its mean grew by more than this many noise standard deviations.
NOISE_FACTOR = 2.0


def group_key(row: Row) -> tuple[str, str, str]:
    return str(row["family"]), str(row["backend"]), str(row["scale"])


def _float(value: object) -> float:
    """A CSV cell or a number as a float (NaN for empty, None or n/a)."""
    if value is None or value == "" or value == "n/a":
        return math.nan
    return float(value)  # type: ignore[arg-type]


def failed(row: Row) -> bool:
    return bool(row.get("error"))


def held_pct(row: Row, what: str = "held") -> float:
    """% of the run's frames held (`what` ``coasted``: of those, dead-reckoned)."""
    frames = _float(row.get("frames"))
    return 100.0 * _float(row.get(what)) / frames if frames and frames > 0 else math.nan


def placed_pct(row: Row, mode: str) -> float:
    """% of the run's frames the map placed by `mode` (NaN with vo: no placements)."""
    value, frames = _float(row.get(f"placed_{mode}")), _float(row.get("frames"))
    return 100.0 * value / frames if math.isfinite(value) and frames > 0 else math.nan


def metric(row: Row, name: str) -> float:
    return held_pct(row) if name == "held_pct" else _float(row.get(name))


def _nanmean(values: Iterable[float]) -> float:
    finite = [v for v in values if math.isfinite(v)]
    return float(np.mean(finite)) if finite else math.nan


def groups(rows: list[Row]) -> dict[tuple[str, str, str], list[Row]]:
    """The rows by group, groups in the order they first appear."""
    grouped: dict[tuple[str, str, str], list[Row]] = {}
    for row in rows:
        grouped.setdefault(group_key(row), []).append(row)
    return grouped


def group_stats(rows: list[Row]) -> dict[str, float]:
    """Per metric: the mean over the group's runs that did not fail, and ``<metric>_noise``: the sample standard
    deviation over seeds of each seed's mean (NaN with one seed); ``runs``, ``failed``, and ``placed_<mode>``
    means in % of frames."""
    good = [r for r in rows if not failed(r)]
    stats: dict[str, float] = {"runs": float(len(rows)), "failed": float(len(rows) - len(good))}
    seeds = sorted({int(_float(r["seed"])) for r in good})
    for name in METRICS:
        stats[name] = _nanmean(metric(r, name) for r in good)
        per_seed = [_nanmean(metric(r, name) for r in good if int(_float(r["seed"])) == s) for s in seeds]
        per_seed = [v for v in per_seed if math.isfinite(v)]
        stats[f"{name}_noise"] = float(np.std(per_seed, ddof=1)) if len(per_seed) > 1 else math.nan
    for mode in ("map", "two_view", "relocalised", "coasted", "lost"):
        stats[f"placed_{mode}"] = _nanmean(placed_pct(r, mode) for r in good)
    stats["coasted_pct"] = _nanmean(held_pct(r, "coasted") for r in good)
    return stats


def worst(rows: list[Row]) -> Row | None:
    """The group's worst run: the largest ATE after Sim(3) (a failed run is not scored: None when all failed)."""
    good = [r for r in rows if not failed(r) and math.isfinite(_float(r["ate_sim3"]))]
    return max(good, key=lambda r: _float(r["ate_sim3"])) if good else None


def _held(held: float, coasted: float) -> str:
    return f"{_cell(held, 1)} ({_cell(coasted, 1)})"


def _cell(value: float, digits: int = 3) -> str:
    return "n/a" if not math.isfinite(value) else f"{value:.{digits}f}"


def _placed(values: dict[str, float]) -> str:
    """``PnP 81 / 2-view 17 / other 2`` (% of frames), or ``-`` with vo."""
    if not math.isfinite(values.get("placed_map", math.nan)):
        return "-"
    other = sum(values.get(f"placed_{m}", 0.0) or 0.0 for m in ("relocalised", "coasted", "lost")
                if math.isfinite(values.get(f"placed_{m}", math.nan)))
    return f"{values['placed_map']:.0f} / {values['placed_two_view']:.0f} / {other:.0f}"


HEADER = ("| group | backend | scale | row | runs | ATE Sim(3) m | ATE m | t_err % | final rot ° | "
          "held % (dead-reckoned) | "
          "placed % PnP / 2-view / other | noise: ATE Sim(3) std over seeds m |")


def table(rows: list[Row]) -> str:
    """The Markdown table: per group a mean row and a worst row (its case and seed), then the failures."""
    lines = [HEADER, "|" + "---|" * HEADER.count(" | ") + "---|"]
    failures = []
    for (family, backend, scale), members in groups(rows).items():
        stats = group_stats(members)
        runs = f"{int(stats['runs'] - stats['failed'])}" + (f" ({int(stats['failed'])} failed)"
                                                            if stats["failed"] else "")
        lines.append(f"| {family} | {backend} | {scale} | mean | {runs} | {_cell(stats['ate_sim3'])} | "
                     f"{_cell(stats['ate'])} | {_cell(stats['t_err'], 2)} | {_cell(stats['rotation_deg'], 2)} | "
                     f"{_held(stats['held_pct'], stats['coasted_pct'])} | {_placed(stats)} | "
                     f"{_cell(stats['ate_sim3_noise'])} |")
        bad = worst(members)
        if bad is not None:
            placed = {f"placed_{m}": placed_pct(bad, m) for m in ("map", "two_view", "relocalised", "coasted",
                                                                   "lost")}
            lines.append(f"| | | | worst: {bad['case']} seed {bad['seed']} | 1 | {_cell(_float(bad['ate_sim3']))} | "
                         f"{_cell(_float(bad['ate']))} | {_cell(_float(bad['t_err']), 2)} | "
                         f"{_cell(_float(bad['rotation_deg']), 2)} | "
                         f"{_held(held_pct(bad), held_pct(bad, 'coasted'))} | {_placed(placed)} |"
                         " |")
        failures += [r for r in members if failed(r)]
    return "\n".join(lines + (["", "Failed runs:", *_failure_lines(failures)] if failures else []))


def _failure_lines(rows: list[Row]) -> list[str]:
    """One line per (family, case, error): the runs that failed with it, then the error (first 200 characters)."""
    by_error: dict[tuple[str, str, str], list[str]] = {}
    for r in rows:
        by_error.setdefault((str(r["family"]), str(r["case"]), str(r["error"])), []).append(
            f"{r['backend']} {r['scale']} seed {r['seed']}")
    return [f"- {family} {case} ({', '.join(runs)}): {error[:200]}" for (family, case, error), runs in by_error.items()]


def write_csv(path: Path, rows: list[Row]) -> None:
    with path.open("w", newline="") as handle:
        writer = csv.DictWriter(handle, FIELDS, extrasaction="ignore")
        writer.writeheader()
        for row in rows:
            writer.writerow({k: _csv_value(row.get(k)) for k in FIELDS})


def _csv_value(value: object) -> object:
    if isinstance(value, float) and not math.isfinite(value):
        return ""
    return "" if value is None else value


def read_csv(path: Path) -> list[Row]:
    with path.open(newline="") as handle:
        reader = csv.DictReader(handle)
        missing = [k for k in ("family", "backend", "scale", "seed", "ate_sim3") if k not in (reader.fieldnames or [])]
        if missing:
            raise ValueError(f"{path}: not a matrix CSV (no column {', '.join(missing)})")
        return [dict(row) for row in reader]


def compare(before: list[Row], after: list[Row]) -> tuple[str, list[str]]:
    """Per group the change of each metric's mean (after − before) and whether it is worse beyond its noise
    (more than `NOISE_FACTOR` × the larger of the two noises; a group whose noise is unmeasured — one seed — is
    flagged for any worsening, as are groups with more failed runs). Returns the Markdown table and the flagged
    groups. The matrix as a whole: the mean over groups of the relative change of ATE after Sim(3). Only the runs
    both CSVs hold (same family, case, backend, scale and seed) are compared: a `--quick` CSV against a whole
    matrix compares its own runs; and the means only over the runs finished in both (a run that failed before,
    e.g. a sequence the code could not read then, would otherwise change a mean by being in it)."""
    def run_key(row: Row) -> tuple[str, ...]:
        return tuple(str(row[k]) for k in ("family", "case", "backend", "scale")) + (str(int(_float(row["seed"]))),)

    both = {run_key(r) for r in before} & {run_key(r) for r in after}
    finished = {run_key(r) for r in before if not failed(r)} & {run_key(r) for r in after if not failed(r)}
    old = groups([r for r in before if run_key(r) in both])
    new = groups([r for r in after if run_key(r) in both])
    gone = [k for k in groups(before) if k not in new] + [k for k in groups(after) if k not in old]
    lines = ["| group | backend | scale | ATE Sim(3) m before → after | Δ ATE m | Δ t_err % | Δ final rot ° | "
             "Δ held % | failed before → after | verdict |", "|---|---|---|---|---|---|---|---|---|---|"]
    flagged, relative = [], []
    for key in [k for k in new if k in old]:
        a = group_stats([r for r in old[key] if run_key(r) in finished]) | {"failed": sum(map(failed, old[key]))}
        b = group_stats([r for r in new[key] if run_key(r) in finished]) | {"failed": sum(map(failed, new[key]))}
        worse = []
        for name in METRICS:
            delta = b[name] - a[name]
            if not math.isfinite(delta) or delta <= 0:
                continue
            noises = [n for n in (a[f"{name}_noise"], b[f"{name}_noise"]) if math.isfinite(n)]
            noise = max(noises) if noises else math.nan
            if not math.isfinite(noise) or delta > NOISE_FACTOR * noise:
                worse.append(name + ("" if math.isfinite(noise) else " (noise unmeasured)"))
        if b["failed"] > a["failed"]:
            worse.append("more failed runs")
        if math.isfinite(a["ate_sim3"]) and math.isfinite(b["ate_sim3"]) and a["ate_sim3"] > 0:
            relative.append(b["ate_sim3"] / a["ate_sim3"] - 1.0)
        verdict = "WORSE beyond noise: " + ", ".join(worse) if worse else "ok"
        if worse:
            flagged.append(f"{key[0]} {key[1]} {key[2]}: " + ", ".join(worse))
        lines.append(f"| {key[0]} | {key[1]} | {key[2]} | {_cell(a['ate_sim3'])} → {_cell(b['ate_sim3'])} | "
                     f"{_signed(b['ate_sim3'] - a['ate_sim3'], 3)} | {_signed(b['t_err'] - a['t_err'], 2)} | "
                     f"{_signed(b['rotation_deg'] - a['rotation_deg'], 2)} | "
                     f"{_signed(b['held_pct'] - a['held_pct'], 1)} | {int(a['failed'])} → {int(b['failed'])} | "
                     f"{verdict} |")
    only = [f"{k[0]} {k[1]} {k[2]}" for k in dict.fromkeys(gone)]
    whole = _nanmean(relative)
    lines += ["", f"Compared: the {len(both)} runs both CSVs hold, means over the {len(finished)} finished in both.",
              f"Matrix as a whole: ATE after Sim(3) {100 * whole:+.1f} % (mean over {len(relative)} groups of "
              "each group's relative change)" if relative else "", f"Groups worse beyond their noise: {len(flagged)}"]
    if only:
        lines.append("Not compared (no run in both CSVs): " + "; ".join(only))
    return "\n".join(line for line in lines if line is not None), flagged


def _signed(value: float, digits: int) -> str:
    return "n/a" if not math.isfinite(value) else f"{value:+.{digits}f}"
