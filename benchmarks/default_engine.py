"""Which backend is the default: issue 53's rule, applied to a development-matrix CSV (benchmarks/matrix.py).

    python -m benchmarks.default_engine after.csv

The map becomes the default when, on the same runs (family, case, seed):
- with ground-truth scale, every KITTI row: ATE after Sim(3) of the map <= 1.05 x vo's + 2 cm;
- without a scale source, the map is more accurate than vo: mean ATE after Sim(3) over the KITTI rows lower,
  and every other family's mean (TUM, synthetic, lens, hand-held) lower or within 1 cm;
- (speed, >= 2.5x the paper configuration on 2 cores, is benchmarks/speed.py's, not a matrix column).
It prints each rule's worst row and exits 1 when a rule fails.
"""

from __future__ import annotations

import argparse
import sys
from collections import defaultdict
from pathlib import Path

from benchmarks.matrix_table import Row, failed, metric, read_csv

GT_FACTOR, GT_MARGIN_M = 1.05, 0.02  # issue 53 item 7
NONE_MARGIN_M = 0.01  # a non-KITTI family's mean without scale may be this much worse (seed noise of a few mm)


def paired(rows: list[Row], scale: str) -> list[tuple[Row, Row]]:
    """(vo, map) rows of the same family, case and seed at `scale`, both finished."""
    by_key: dict[tuple[str, str, str], dict[str, Row]] = defaultdict(dict)
    for row in rows:
        if row["scale"] == scale and not failed(row):
            by_key[(str(row["family"]), str(row["case"]), str(row["seed"]))][str(row["backend"])] = row
    return [(pair["vo"], pair["map"]) for _, pair in sorted(by_key.items()) if {"vo", "map"} <= pair.keys()]


def _label(row: Row) -> str:
    return f"{row['family']} {row['case']} seed {row['seed']}"


def gt_rule(rows: list[Row]) -> tuple[bool, list[str]]:
    """Every KITTI row with ground-truth scale: map <= 1.05 x vo + 2 cm (ATE after Sim(3))."""
    lines, ok = [], True
    for vo, map_ in paired(rows, "gt"):
        if not str(vo["family"]).startswith("KITTI"):
            continue
        bound = GT_FACTOR * metric(vo, "ate_sim3") + GT_MARGIN_M
        if metric(map_, "ate_sim3") > bound:
            ok = False
            lines.append(f"  FAIL {_label(vo)}: map {metric(map_, 'ate_sim3'):.3f} m > {bound:.3f} m "
                         f"(vo {metric(vo, 'ate_sim3'):.3f} m)")
    return ok, lines


def none_rule(rows: list[Row]) -> tuple[bool, list[str]]:
    """Without scale, per family: mean ATE after Sim(3) of the map below vo's (KITTI) or within 1 cm (others)."""
    per_family: dict[str, list[tuple[float, float]]] = defaultdict(list)
    for vo, map_ in paired(rows, "none"):
        family = "KITTI" if str(vo["family"]).startswith("KITTI") else str(vo["family"])
        per_family[family].append((metric(vo, "ate_sim3"), metric(map_, "ate_sim3")))
    lines, ok = [], True
    for family, pairs in sorted(per_family.items()):
        vo_mean = sum(v for v, _ in pairs) / len(pairs)
        map_mean = sum(m for _, m in pairs) / len(pairs)
        worse = sum(m > v for v, m in pairs)
        good = map_mean < vo_mean if family == "KITTI" else map_mean <= vo_mean + NONE_MARGIN_M
        ok &= good
        lines.append(f"  {'ok  ' if good else 'FAIL'} {family}: mean map {map_mean:.3f} m, vo {vo_mean:.3f} m "
                     f"({len(pairs)} runs, map worse on {worse})")
    return ok, lines


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("csv", type=Path, help="a development-matrix CSV (python -m benchmarks.matrix --csv)")
    args = parser.parse_args(argv)
    rows = read_csv(args.csv)
    gt_ok, gt_lines = gt_rule(rows)
    none_ok, none_lines = none_rule(rows)
    print(f"ground-truth scale, every KITTI row map <= {GT_FACTOR} x vo + {GT_MARGIN_M * 100:.0f} cm: "
          f"{'met' if gt_ok else 'not met'} ({len(paired(rows, 'gt'))} pairs)")
    print("\n".join(gt_lines) if gt_lines else "  every row within the bound")
    print(f"no scale source, map more accurate than vo: {'met' if none_ok else 'not met'}")
    print("\n".join(none_lines))
    return 0 if gt_ok and none_ok else 1


if __name__ == "__main__":
    sys.exit(main())
