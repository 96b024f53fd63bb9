"""FAST corners spread over the image, and pyramidal KLT tracking with a forward–backward check.

Images are (H, W) uint8 grey. Points are (N, 2) float32 pixel coordinates (x right, y down).
"""

from __future__ import annotations

import cv2
import numpy as np

from vslam_core.config import DetectorConfig, TrackerConfig


def grid_cells(points: np.ndarray, shape: tuple[int, int], grid: tuple[int, int]) -> np.ndarray:
    """(N,) int64 row-major index of the cell of a (rows, cols) grid over an (H, W) image holding each (N, 2)
    point (points outside the image: the nearest border cell)."""
    height, width = shape
    rows, cols = grid
    return (np.clip((points[:, 1] * rows / height).astype(np.int64), 0, rows - 1) * cols
            + np.clip((points[:, 0] * cols / width).astype(np.int64), 0, cols - 1))


def grid_coverage(points: np.ndarray, shape: tuple[int, int], config: DetectorConfig) -> float:
    """Share of the grid_rows x grid_cols cells (`grid_cells`) that hold at least one of the (N, 2) points."""
    grid = (config.grid_rows, config.grid_cols)
    return len(np.unique(grid_cells(points, shape, grid))) / (grid[0] * grid[1])


def detect_corners(
    image: np.ndarray, existing: np.ndarray, wanted: int, config: DetectorConfig,
    region: tuple[int, int, int, int] | None = None, usable: np.ndarray | None = None,
) -> np.ndarray:
    """Up to `wanted` FAST corners, strongest first within each cell of a grid_rows x grid_cols grid and
    at least `min_distance_px` from every `existing` (M, 2) point, so new corners fill the empty parts of
    the image instead of piling up on one façade. `region` (x0, y0, x1, y1) limits the search to a
    rectangle; `usable` (H, W) uint8 (0 = not usable: a lens's unusable border) excludes pixels. Returns
    (K, 2) float32 full-image coordinates, K ≤ wanted."""
    if wanted <= 0:
        return np.zeros((0, 2), np.float32)
    if region is not None:
        x0, y0, x1, y1 = region
        offset = np.array([x0, y0], np.float32)
        found = detect_corners(image[y0:y1, x0:x1], existing - offset, wanted, config,
                               usable=None if usable is None else usable[y0:y1, x0:x1])
        return found + offset
    height, width = image.shape
    mask = None if usable is None else usable.copy()
    if config.min_distance_px > 0 and len(existing):
        mask = np.full((height, width), 255, np.uint8) if mask is None else mask
        circle, radius = cv2.circle, config.min_distance_px
        for centre in np.round(existing).astype(np.int32).tolist():  # [x, y] lists: a third of the loop's time
            circle(mask, centre, radius, 0, -1)
    detector = cv2.FastFeatureDetector_create(threshold=config.fast_threshold, nonmaxSuppression=True)
    keypoints = detector.detect(image, mask)
    if not keypoints:
        return np.zeros((0, 2), np.float32)
    points = cv2.KeyPoint_convert(keypoints).astype(np.float32).reshape(-1, 2)
    response = np.array([kp.response for kp in keypoints], np.float32)
    cells = config.grid_rows * config.grid_cols
    if cells == 1:
        order = np.argsort(-response, kind="stable")[:wanted]
        return points[order]
    cell = grid_cells(points, (height, width), (config.grid_rows, config.grid_cols))  # corners lie inside the image
    # Rank of each corner inside its cell by response; take rank 0 of every cell, then rank 1, ...
    order = np.lexsort((-response, cell))
    sorted_cell = cell[order]
    first_of_cell = np.searchsorted(sorted_cell, sorted_cell, side="left")
    rank = np.arange(len(order)) - first_of_cell
    by_rank = order[np.lexsort((-response[order], rank))]
    return points[by_rank[:wanted]]


def fill_flow(flow: np.ndarray, points: np.ndarray, image_shape: tuple[int, int], grid: tuple[int, int]) -> np.ndarray:
    """(N, 2) flow with its NaN rows (tracks with no flow history yet) replaced by the mean flow of the
    known rows in the same cell of a (rows, cols) grid over the image; rows whose cell has no known flow
    stay NaN. Neighbours move alike, so a new track can start near where it will be found."""
    known = ~np.isnan(flow[:, 0])
    if known.all() or not known.any():
        return flow
    rows, cols = grid
    cell = grid_cells(points, image_shape, grid)
    count = np.bincount(cell[known], minlength=rows * cols)
    with np.errstate(invalid="ignore", divide="ignore"):
        mean = np.column_stack([np.bincount(cell[known], flow[known, axis], rows * cols) / count for axis in (0, 1)])
    filled = flow.copy()
    filled[~known] = mean[cell[~known]]
    return filled


def track_points(
    previous: np.ndarray,
    current: np.ndarray,
    points: np.ndarray,
    config: TrackerConfig,
    predicted: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Track (N, 2) float32 points from the previous into the current (H, W) uint8 frame.

    predicted: optional (N, 2) guess of each point's position in the current frame (NaN rows: no guess).
    Guessed points search `predicted_max_level` pyramid levels from their guess, the others `max_level`
    levels from their own position.

    Returns (tracked (N, 2) float32, ok (N,) bool — KLT converged and the point stays inside the image,
    fb_error (N,) float32 — distance between a point and its forward-then-backward track, inf where the
    forward track failed). The forward–backward check itself (fb_error ≤ threshold) is the caller's.
    """
    if len(points) == 0:
        return np.zeros((0, 2), np.float32), np.zeros(0, bool), np.zeros(0, np.float32)
    points = points.astype(np.float32)
    guessed = np.zeros(len(points), bool)
    if predicted is not None and config.predicted_max_level >= 0:
        guessed = ~np.isnan(predicted[:, 0])
    tracked = np.empty_like(points)
    ok = np.zeros(len(points), bool)
    for subset, start, level in ((~guessed, None, config.max_level), (guessed, predicted, config.predicted_max_level)):
        if subset.any():
            tracked[subset], ok[subset] = _lucas_kanade(previous, current, points[subset],
                                                        None if start is None else start[subset], level, config)
    ok &= _inside(tracked, current.shape, config.border_px)
    fb_error = _backward(previous, current, points, tracked, ok, config)
    if config.retry_failed_share < 1.0 and guessed.any() and np.isfinite(config.fb_threshold_px):
        # guesses off by more than their few levels reach (a turn whose rate changes) fail together: again from
        # them, every level; lone failures (a point occluded, gone) are left alone
        again = guessed & ~(fb_error <= config.fb_threshold_px)
        if again.sum() > config.retry_failed_share * guessed.sum():
            assert predicted is not None
            retried, retried_ok = _lucas_kanade(previous, current, points[again], predicted[again], config.max_level,
                                                config)
            retried_ok &= _inside(retried, current.shape, config.border_px)
            retried_fb = _backward(previous, current, points[again], retried, retried_ok, config)
            better = retried_fb <= config.fb_threshold_px
            rows = np.flatnonzero(again)[better]
            tracked[rows], ok[rows], fb_error[rows] = retried[better], True, retried_fb[better]
    return tracked, ok, fb_error


def _inside(tracked: np.ndarray, shape: tuple[int, ...], border: int) -> np.ndarray:
    """(N,) bool: the (N, 2) points lie at least `border` px inside an image of `shape`."""
    height, width = shape[:2]
    return np.asarray((tracked[:, 0] >= border) & (tracked[:, 0] < width - border) & (tracked[:, 1] >= border)
                      & (tracked[:, 1] < height - border))


def _backward(previous: np.ndarray, current: np.ndarray, points: np.ndarray, tracked: np.ndarray, ok: np.ndarray,
              config: TrackerConfig) -> np.ndarray:
    """(N,) float32 forward–backward error of the `ok` tracks (inf elsewhere; 0 with the check disabled)."""
    fb_error = np.full(len(points), np.inf, np.float32)
    if np.isfinite(config.fb_threshold_px) and ok.any():
        back, back_ok = _lucas_kanade(current, previous, tracked[ok], points[ok], config.backward_max_level, config)
        err = np.linalg.norm(back - points[ok], axis=1)
        err[~back_ok] = np.inf
        fb_error[ok] = err
    elif ok.any():
        fb_error[ok] = 0.0  # check disabled
    return fb_error


def _lucas_kanade(
    previous: np.ndarray, current: np.ndarray, points: np.ndarray, start: np.ndarray | None, max_level: int,
    config: TrackerConfig,
) -> tuple[np.ndarray, np.ndarray]:
    """One cv2.calcOpticalFlowPyrLK call: (M, 2) points → ((M, 2) tracked, (M,) status), searching from
    `start` (M, 2) when given."""
    criteria = (cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_COUNT, config.max_iterations, config.epsilon)
    flags = 0 if start is None else cv2.OPTFLOW_USE_INITIAL_FLOW
    guess = None if start is None else start.reshape(-1, 1, 2).astype(np.float32)  # a copy: OpenCV writes to it
    moved, status, _ = cv2.calcOpticalFlowPyrLK(
        previous, current, points.reshape(-1, 1, 2), guess, winSize=(config.window_px, config.window_px),
        maxLevel=max_level, criteria=criteria, flags=flags,
    )
    return moved.reshape(-1, 2), status.reshape(-1).astype(bool)


def match_features(
    first: np.ndarray, second: np.ndarray, max_features: int = 5000, ratio: float = 0.9
) -> tuple[np.ndarray, np.ndarray]:
    """ORB descriptors matched between two frames that tracks cannot bridge (a gap, a jump): mutual
    best Hamming matches passing Lowe's ratio test (loose: RANSAC follows). Returns (M, 2) float32 points
    in each frame."""
    orb = cv2.ORB_create(nfeatures=max_features, fastThreshold=10)
    kp1, d1 = orb.detectAndCompute(first, None)
    kp2, d2 = orb.detectAndCompute(second, None)
    if d1 is None or d2 is None or len(kp1) < 2 or len(kp2) < 2:
        return np.zeros((0, 2), np.float32), np.zeros((0, 2), np.float32)
    first_index, second_index = match_descriptors(d1, d2, ratio)
    first_points = np.array([kp1[i].pt for i in first_index], np.float32).reshape(-1, 2)
    second_points = np.array([kp2[j].pt for j in second_index], np.float32).reshape(-1, 2)
    return first_points, second_points


def match_descriptors(query: np.ndarray, train: np.ndarray, ratio: float) -> tuple[np.ndarray, np.ndarray]:
    """Mutual nearest Hamming matches between (Q, 32) and (T, 32) uint8 ORB descriptors that pass Lowe's
    ratio test. Returns (matched query indices, matched train indices), each (M,) int64, by query.

    Each query's two nearest train descriptors, then, only for the train descriptors some query chose and passed
    the ratio test with, their nearest query (ties: the first, both ways, as OpenCV's brute-force matcher): the
    same matches as matching both ways in full, in about half the time."""
    none = np.zeros(0, np.int64), np.zeros(0, np.int64)
    if len(query) < 2 or len(train) < 2:
        return none
    distance, nearest = cv2.batchDistance(query, train, cv2.CV_32S, normType=cv2.NORM_HAMMING, K=2)  # (Q, 2)
    rows = np.flatnonzero(distance[:, 0] < ratio * distance[:, 1])
    chosen = nearest[rows, 0]
    columns = np.unique(chosen)
    if not len(columns):
        return none
    _, back = cv2.batchDistance(train[columns], query, cv2.CV_32S, normType=cv2.NORM_HAMMING, K=1)  # (C, 1)
    mutual = back[np.searchsorted(columns, chosen), 0] == rows
    return rows[mutual].astype(np.int64), chosen[mutual].astype(np.int64)
