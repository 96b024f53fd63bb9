"""The default thresholds of a first divergence in `vslam compare` (no imports: the CLI reads them at start-up)."""

#: Default thresholds of a divergence: a frame's step rotation differs by more than this many degrees…
#: Measured (KITTI frames 0:150, `vslam run --detail summary`, odometry backend, scale gt; per-frame maxima over
#: the window): different RANSAC seeds ([pose] seed 0 vs 1) differ by at most 0.040° / 1.3 % of the step (05)
#: and 0.032° / 1.3 % (00); a different FAST threshold (20 vs 30) by at most 0.090° / 2.7 % (05) and 0.045° /
#: 1.2 % (00). The defaults are ~5× and ~4× the largest of these; a planted 2° kink is found at its frame.
ROTATION_DEG = 0.5
#: … or its translation differs by more than this % of the baseline's step.
TRANSLATION_PCT = 10.0
