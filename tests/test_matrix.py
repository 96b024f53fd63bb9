"""The development matrix's table, CSV and comparison (benchmarks/matrix_table.py) on made-up rows: no engine runs."""

from __future__ import annotations

import math
from pathlib import Path

import pytest

from benchmarks.matrix import FAMILIES, QUICK_FAMILIES, make_jobs, run_matrix
from benchmarks.matrix import main as matrix_main
from benchmarks.matrix_table import compare, group_stats, read_csv, table, worst, write_csv


def _row(family: str, case: str, backend: str, seed: int, ate_sim3: float, *, scale: str = "gt",
         error: str = "", held: int = 0, placed: tuple[int, int] | None = None) -> dict[str, object]:
    row: dict[str, object] = {"family": family, "case": case, "backend": backend, "scale": scale, "seed": seed,
                              "frames": 100, "error": error, "ate_sim3": ate_sim3 if not error else math.nan,
                              "ate": 2 * ate_sim3, "t_err": math.nan, "rotation_deg": 1.0, "held": held,
                              "coasted": 0, "seconds": 1.0}
    if placed is not None:
        row.update(placed_map=placed[0], placed_two_view=placed[1], placed_relocalised=0, placed_coasted=0,
                   placed_init=1, placed_lost=0)
    return row


def _rows(shift: float = 0.0) -> list[dict[str, object]]:
    """Two groups: KITTI vo (seeds 0, 1 of two cases; noise ~0.01 m) and TUM map (one run failed)."""
    return [
        _row("KITTI step 1", "00 0:150", "vo", 0, 0.50 + shift),
        _row("KITTI step 1", "05 0:150", "vo", 0, 0.30 + shift),
        _row("KITTI step 1", "00 0:150", "vo", 1, 0.52 + shift),
        _row("KITTI step 1", "05 0:150", "vo", 1, 0.30 + shift, held=10),
        _row("TUM hand-held", "xyz", "map", 0, 0.05, placed=(80, 19)),
        _row("TUM hand-held", "desk", "map", 0, 0.0, error="SourceError: no ground truth at frame 41"),
    ]


def test_group_mean_worst_noise_and_placements() -> None:
    stats = group_stats(_rows()[:4])
    assert stats["ate_sim3"] == pytest.approx(0.405)
    assert stats["ate"] == pytest.approx(0.81)
    assert stats["held_pct"] == pytest.approx(2.5)  # 10 of 400 frames
    # seed means 0.40 and 0.41: sample std 0.00707
    assert stats["ate_sim3_noise"] == pytest.approx(0.01 / math.sqrt(2))
    bad = worst(_rows()[:4])
    assert bad is not None and bad["case"] == "00 0:150" and bad["seed"] == 1
    tum = group_stats(_rows()[4:])
    assert tum["failed"] == 1 and tum["ate_sim3"] == pytest.approx(0.05) and math.isnan(tum["ate_sim3_noise"])
    assert tum["placed_map"] == pytest.approx(80.0) and tum["placed_two_view"] == pytest.approx(19.0)


def test_table_has_a_mean_and_a_worst_row_per_group_and_lists_failures() -> None:
    text = table(_rows())
    lines = text.splitlines()
    assert "| KITTI step 1 | vo | gt | mean | 4 | 0.405 | 0.810 | n/a | 1.00 | 2.5 (0.0) | - | 0.007 |" in lines
    assert any(line.startswith("| | | | worst: 00 0:150 seed 1 | 1 | 0.520 |") for line in lines)
    assert "| TUM hand-held | map | gt | mean | 1 (1 failed) | 0.050 | 0.100 | n/a | 1.00 | 0.0 (0.0) | 80 / 19 / 0 |" \
        in text
    assert "- TUM hand-held desk (map gt seed 0): SourceError: no ground truth at frame 41" in lines


def test_csv_round_trip_gives_the_same_table(tmp_path: Path) -> None:
    path = tmp_path / "m.csv"
    write_csv(path, _rows())
    assert table(read_csv(path)) == table(_rows())
    (tmp_path / "bad.csv").write_text("a,b\n1,2\n")
    with pytest.raises(ValueError, match="not a matrix CSV"):
        read_csv(tmp_path / "bad.csv")


def test_compare_flags_a_group_worse_beyond_its_noise_only() -> None:
    _, within = compare(_rows(), _rows(shift=0.01))  # 0.01 m < 2 × noise (0.014 m)
    assert within == []
    text, beyond = compare(_rows(), _rows(shift=0.05))
    assert beyond == ["KITTI step 1 vo gt: ate_sim3, ate"]
    assert "| KITTI step 1 | vo | gt | 0.405 → 0.455 | +0.050 |" in text
    assert "Matrix as a whole: ATE after Sim(3) +6.2 %" in text  # +12.3 % and 0 % over the two groups
    better, none = compare(_rows(), _rows(shift=-0.05))
    assert none == [] and "-0.050" in better


def test_compare_flags_more_failures_and_unmeasured_noise() -> None:
    after = _rows()
    after[4] = _row("TUM hand-held", "xyz", "map", 0, 0.06, error="RuntimeError: lost")
    _, flagged = compare(_rows(), after)
    assert flagged == ["TUM hand-held map gt: more failed runs"]
    after[4] = _row("TUM hand-held", "xyz", "map", 0, 0.06, placed=(80, 19))
    _, flagged = compare(_rows(), after)  # one seed: any worsening is flagged
    assert flagged == ["TUM hand-held map gt: ate_sim3 (noise unmeasured), ate (noise unmeasured)"]


def test_cli_prints_a_saved_csv_and_its_comparison(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    before, after = tmp_path / "before.csv", tmp_path / "after.csv"
    write_csv(before, _rows())
    write_csv(after, _rows(shift=0.05))
    matrix_main(["--table", str(after), "--compare", str(before)])
    printed = capsys.readouterr().out
    assert "| KITTI step 1 | vo | gt | mean | 4 | 0.455 |" in printed
    assert "  worse: KITTI step 1 vo gt: ate_sim3, ate" in printed
    with pytest.raises(SystemExit) as exit_info:
        matrix_main(["--table", str(tmp_path / "missing.csv")])
    assert exit_info.value.code == 2


def test_jobs_cover_every_family_backend_scale_and_seed_and_resume_keeps_done_rows() -> None:
    folders = {"lens-00": "l0", "lens-05": "l5", "handheld": "h", "small-00": "s0", "small-05": "s5"}
    jobs = make_jobs(list(FAMILIES), [0, 1], "kitti", "tum", folders, quick=False)
    kitti = [j for j in jobs if j.kind == "kitti"]
    assert {j.family for j in kitti} == {"KITTI step 1", "KITTI step 2", "KITTI step 3"}
    assert {j.scale for j in kitti} == {"gt", "height", "none"}
    assert {j.frames for j in kitti} >= {"0:150", "0:150:3", "150:300:2", "0:300", "0:300:2", "0:300:3"}
    assert {(j.backend, j.seed) for j in jobs} == {("vo", 0), ("vo", 1), ("map", 0), ("map", 1)}
    small = [j for j in jobs if j.family == "KITTI at half size"]  # a smaller camera: the road band in angles
    assert {j.scale for j in small} == {"gt", "height", "none"} and {j.camera_height_m for j in small} == {1.65}
    assert {j.scale for j in jobs if j.kind not in ("kitti", "folder")} == {"gt", "none"}
    assert len({(j.family, j.case, j.backend, j.scale, j.seed) for j in jobs}) == len(jobs) == 304
    quick = make_jobs(list(QUICK_FAMILIES), [0, 1], "kitti", "tum", {}, quick=True)
    assert len(quick) == 48 and {j.family for j in quick} == {"KITTI step 1", "KITTI step 2", "KITTI step 3",
                                                              "TUM hand-held", "synthetic street", "synthetic walk"}
    only = make_jobs(["kitti"], [0], "kitti", "tum", {}, quick=False, backends=("map",), scales_kept=("none",))
    assert {(j.backend, j.scale) for j in only} == {("map", "none")} and len(only) == 18  # --backends, --scales
    # --resume: every row already in the CSV is kept (in the jobs' order), none is run again (no pool started)
    done = [_row(j.family, j.case, j.backend, j.seed, 0.1, scale=j.scale) for j in reversed(quick)]
    kept = run_matrix(quick, 2, None, done)
    assert [(r["case"], r["backend"], r["scale"], r["seed"]) for r in kept] == \
        [(j.case, j.backend, j.scale, j.seed) for j in quick]


def test_compare_takes_only_the_runs_both_csvs_hold() -> None:
    """A subset (a --quick CSV) against the whole matrix: the same runs, not group means over different cases."""
    subset = [row for row in _rows() if row["case"] == "05 0:150"]  # the better case of the KITTI group
    text, flagged = compare(_rows(), subset)
    assert flagged == [] and "Compared: the 2 runs both CSVs hold, means over the 2 finished in both." in text
    assert "| KITTI step 1 | vo | gt | 0.300 → 0.300 | +0.000 |" in text
    assert "Not compared (no run in both CSVs): TUM hand-held map gt" in text


def test_compare_means_only_the_runs_finished_in_both() -> None:
    """A case that failed before (a sequence the code could not read then) and runs now is counted as a failure
    fixed, not averaged into the after mean: the group's other case is what both means hold."""
    before = [_row("TUM hand-held", "xyz", "vo", 0, 0.02), _row("TUM hand-held", "desk", "vo", 0, 0.0, error="x")]
    after = [_row("TUM hand-held", "xyz", "vo", 0, 0.02), _row("TUM hand-held", "desk", "vo", 0, 0.09)]
    text, flagged = compare(before, after)
    assert flagged == [] and "| TUM hand-held | vo | gt | 0.020 → 0.020 | +0.000 |" in text
    assert "| 1 → 0 | ok |" in text and "means over the 1 finished in both" in text
