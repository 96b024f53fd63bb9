"""Trajectories as data: the metrics against ground truth (`metrics`: ATE, RPE, the KITTI devkit's t_err and
r_err, alignments), each frame's own error and its causes (`drift`), and trajectory files (`io`: KITTI, TUM)."""
