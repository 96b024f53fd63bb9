"""Run a source through the engine: one `FrameResult` per input frame, handed to optional sinks.

No I/O beyond reading the source, no Rerun: the CLI passes a recorder as a sink.
"""

from __future__ import annotations

import queue
import threading
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, TypeVar

import numpy as np

from vslam_core.config import EngineConfig, ScaleSource
from vslam_core.engine import Odometry
from vslam_core.mapping.global_adjustment import GlobalAdjusted
from vslam_core.mapping.localisation import MapLocalisation
from vslam_core.mapping.tracking import MapTracking
from vslam_core.results import FrameResult, FrameStatus, LoopStep, Reason, TrackingMode, elapsed_ms
from vslam_core.scale import make_scale_provider
from vslam_core.sources.base import Frame, FrameSource

if TYPE_CHECKING:
    from vslam_core.mapping.storage import StoredMap

FrameSink = Callable[[Frame, FrameResult], None]
Engine = Odometry | MapTracking | MapLocalisation
T = TypeVar("T")


#: How the map backend placed a frame, by tracking mode, in the order a summary lists them.
PLACED = {TrackingMode.MAP: "by PnP against the map", TrackingMode.TWO_VIEW: "by two-view motion",
          TrackingMode.RELOCALISED: "relocalised", TrackingMode.COASTED: "dead-reckoned",
          TrackingMode.INIT: "starting a map", TrackingMode.LOST: "lost (the pose held)"}
#: --scale none: where a two-view step's length came from (map_scale.TwoViewLength), as the summary says it
STEP_LENGTHS = {"landmarks": "measured on landmarks", "tracks": "measured on the tracks of the two frames before",
                "last step": "took the last step's", "speed": "took the map's recent speed"}


@dataclass
class RunResult:
    """The trajectory of a run so far (complete once `run_odometry` returned)."""

    indices: list[int]  # source frame indices, one per processed frame
    timestamps: list[float | None]
    poses: list[np.ndarray]  # (4, 4) T_world_cam per processed frame (map backend: refined by BA once complete)
    # the map backend: each frame's pose as it was tracked (what the per-frame results said), kept when the run
    # ended and `poses` became the refined ones; empty when nothing refines the poses (vo, localising in a map)
    tracked_poses: list[np.ndarray] = field(default_factory=list)
    held: int = 0  # frames not tracked (status held): dead-reckoned, or keeping the previous pose
    coasted: int = 0  # of those, the frames whose pose was dead-reckoned (vslam_core.coasting)
    tracked: int = 0  # frames whose motion was measured (status ok) or dead-reckoned
    held_reasons: dict[str, int] = field(default_factory=dict)  # why frames were held: reason -> frames
    seconds: float = 0.0  # wall time of the whole run, decoding and sinks included
    modes: dict[TrackingMode, int] = field(default_factory=dict)  # map backend: frames per tracking mode
    # map backend, --scale none: two-view frames per source of their step's length (`MapFrame.step_length`)
    step_lengths: dict[str, int] = field(default_factory=dict)
    # map backend, --scale none: frames tracked before the map started, placed again by PnP against its first
    # landmarks once it did (`FramesBeforeMap`): their output poses, not their tracking-time mode, say so
    placed_at_map_start: int = 0
    loops_at_end: list[LoopStep] = field(default_factory=list)  # map backend: the loop searches collected when
    # the run ended (vslam_core/loop/closing.py `finish`); a loop they closed corrected `poses`
    # map backend: the map's adjustment as a whole once the run completed (`map.adjust_at_end`), or why it was not run
    adjusted_at_end: GlobalAdjusted | str | None = None
    # --scale height: steps per outcome of their road-plane fit: "measured" (used), "doubtful" (used, flagged
    # road_plane_doubtful), "held" (no plane, or one far off the trend: the trend's step or the map's scale instead)
    road_planes: dict[str, int] = field(default_factory=dict)
    # map backend with a scale source: (run position, forward share) when the camera was found to move sideways
    # and the map took --scale none's settings from there (`map_scale.sideways_camera`)
    sideways: tuple[int, float] | None = None

    @property
    def frames(self) -> int:
        return len(self.poses)

    @property
    def scored_trajectory(self) -> str:
        """Which poses `poses` (and so every score of the run) are: ``refined`` (the map's, after bundle
        adjustment and loop closing) or ``as tracked``."""
        return "refined" if self.tracked_poses else "as tracked"

    @property
    def adjusted_summary(self) -> str | None:
        """What the map's adjustment at the end did, e.g. ``the newest keyframes once the run ended: 60 of 71 free,
        6306 landmarks, reprojection 0.48 -> 0.42 px, 1.1 s``, or why it was not run; None when it is off (`vo`, a
        scale source for a camera not moving sideways) or the run was interrupted."""
        done = self.adjusted_at_end
        if done is None or isinstance(done, str):
            return done
        return (f"the newest keyframes once the run ended: {done.free} of {done.keyframes} free, {done.landmarks} "
                f"landmarks, reprojection {done.mean_error_before:.2f} -> {done.mean_error_after:.2f} px, "
                f"{done.milliseconds / 1000:.1f} s")

    def settings_summary(self, scale: ScaleSource) -> str | None:
        """Whether the map changed its settings during the run, e.g. ``a camera moving sideways (median |cos| of
        keyframe step and optical axis 0.39 by frame 16): the map's --scale none settings from there, the steps'
        lengths still from gt``; None when it did not."""
        if self.sideways is None:
            return None
        position, share = self.sideways
        return (f"a camera moving sideways (median |cos| of keyframe step and optical axis {share:.2f} by frame "
                f"{self.indices[position] if position < len(self.indices) else position}): the map's --scale none "
                f"settings from there, the steps' lengths still from {scale}")

    def placed_summary(self, scale: ScaleSource) -> str | None:
        """Where the map backend's poses came from, e.g. ``281 by PnP against the map, 18 by two-view motion, 1
        starting a map`` (None with `vo`); with `--scale none`, where a two-view step's length came from."""
        if not self.modes:
            return None
        text = ", ".join(f"{self.modes[mode]} {words}" for mode, words in PLACED.items() if self.modes.get(mode))
        if scale == "none" and self.step_lengths:
            sources = ", ".join(f"{self.step_lengths[name]} {words}" for name, words in STEP_LENGTHS.items()
                                if self.step_lengths.get(name))
            again = (f"; {self.placed_at_map_start} frames tracked before the map started placed again by PnP "
                     "against its first landmarks in the output poses" if self.placed_at_map_start else "")
            text += f" (--scale none: of the two-view steps' lengths, {sources}; the scale can drift there{again})"
        return text

    @property
    def road_summary(self) -> str | None:
        """With --scale height, how many steps measured their length on the road plane, e.g. ``measured on 281 of
        299 steps (35 of them doubtful); 18 without (no plane, or one over max_jump off the trend: the trend's step or
        the map's scale used)``; None without such steps."""
        if not self.road_planes:
            return None
        held, doubtful = self.road_planes.get("held", 0), self.road_planes.get("doubtful", 0)
        total = sum(self.road_planes.values())
        return (f"measured on {total - held} of {total} steps ({doubtful} of them doubtful); {held} without (no plane, "
                "or one over max_jump off the trend: the trend's step or the map's scale used)")

    @property
    def road_warning(self) -> str | None:
        """A warning when under half of 20 or more steps measured the road plane: the metric scale then rests on
        few measurements (a road band that misses the road, a wrong --camera-height, a road hidden by traffic)."""
        total = sum(self.road_planes.values())
        measured = total - self.road_planes.get("held", 0)
        if total < 20 or measured >= 0.5 * total:
            return None
        return (f"--scale height measured the road plane on only {measured} of {total} steps "
                f"({100 * measured / total:.0f} %): the metric scale rests on few measurements (is the road in view "
                "in the band [height] road_top_deg and road_half_width_deg describe, and --camera-height right?)")

    @property
    def held_summary(self) -> str:
        """What became of the frames not tracked, e.g. ``12 not tracked: 11 dead-reckoned, 1 held the previous
        pose``."""
        if not self.coasted:
            return f"{self.held} held the previous pose"
        return (f"{self.held} not tracked: {self.coasted} dead-reckoned, {self.held - self.coasted} held the "
                "previous pose")

    def pose_array(self) -> np.ndarray:
        """(N, 4, 4) poses of the processed frames."""
        return np.array(self.poses).reshape(-1, 4, 4)


def iterate_timed(source: FrameSource) -> Iterator[tuple[Frame, float]]:
    """The source's frames with the milliseconds spent decoding each."""
    iterator = iter(source)
    while True:
        start = time.perf_counter()
        try:
            frame = next(iterator)
        except StopIteration:
            return
        yield frame, elapsed_ms(start)


def prefetched(items: Iterator[T], depth: int = 2) -> Iterator[T]:
    """The items of `items`, produced up to `depth` ahead by a background thread, so decoding the next
    frame overlaps processing this one (cv2.imread releases the GIL). An exception raised by `items` is
    re-raised here, after the items before it; closing this generator stops the thread."""
    buffer: queue.Queue[tuple[str, object]] = queue.Queue(maxsize=depth)
    stop = threading.Event()

    def put(kind: str, value: object) -> bool:
        while not stop.is_set():
            try:
                buffer.put((kind, value), timeout=0.1)
                return True
            except queue.Full:
                continue
        return False

    def produce() -> None:
        try:
            for item in items:
                if not put("item", item):
                    return
        except BaseException as exc:  # noqa: BLE001 - handed to the consumer, which re-raises it
            put("error", exc)
            return
        put("end", None)

    worker = threading.Thread(target=produce, name="vslam-prefetch", daemon=True)
    worker.start()
    try:
        while True:
            kind, value = buffer.get()
            if kind == "end":
                return
            if kind == "error":
                assert isinstance(value, BaseException)
                raise value
            yield value  # type: ignore[misc]
    finally:
        stop.set()
        worker.join()


def run_odometry(
    source: FrameSource,
    config: EngineConfig,
    sinks: tuple[FrameSink, ...] = (),
    result: RunResult | None = None,
    prior_map: StoredMap | None = None,
    finish: Callable[[Engine], None] | None = None,
) -> RunResult:
    """Estimate one pose per source frame. Fills `result` as it goes (pass one in to keep the frames
    processed so far if the run is interrupted). With `prior_map`, each frame is localised in that map
    (`MapLocalisation`) instead. `finish` is given the engine once every frame was processed (e.g. to save
    the map)."""
    config = config.for_image_width(source.intrinsics.width)  # pixel sizes scaled for a wide camera
    # the height scale is never given the ground truth
    ground_truth = source.ground_truth if config.scale == "gt" else None
    scale = make_scale_provider(config, ground_truth, source.intrinsics.K, source.camera_height)
    engine: Engine
    if prior_map is not None:
        engine = MapLocalisation(source.intrinsics, config, prior_map)
    else:
        engine = (MapTracking if config.backend == "map" else Odometry)(source.intrinsics, config, scale)
        if isinstance(engine, MapTracking) and engine.loop is not None:
            engine.loop.keep_places = finish is not None  # only `finish` (saving the map) reads every keyframe's
    run = result if result is not None else RunResult([], [], [])
    start = time.perf_counter()
    completed = False
    try:
        frames = iterate_timed(source)
        for frame, decode_ms in prefetched(frames) if config.threads > 1 else frames:
            frame_result = engine.process(frame)
            frame_result.timings_ms["decode"] = decode_ms
            run.indices.append(frame.index)
            run.timestamps.append(frame.timestamp)
            run.poses.append(frame_result.T_world_cam)
            run.held += frame_result.status == FrameStatus.HELD
            reasons = frame_result.health.reasons
            coasted = Reason.COASTED in reasons
            run.coasted += frame_result.status == FrameStatus.HELD and coasted
            run.tracked += frame_result.status == FrameStatus.OK or coasted
            if frame_result.mapping is not None:
                mode = frame_result.mapping.mode
                run.modes[mode] = run.modes.get(mode, 0) + 1
                if (length_from := frame_result.mapping.step_length) is not None:
                    run.step_lengths[length_from] = run.step_lengths.get(length_from, 0) + 1
            if (road := frame_result.scale_estimate) is not None:
                outcome = "held" if road.held else "doubtful" if road.doubtful else "measured"
                run.road_planes[outcome] = run.road_planes.get(outcome, 0) + 1
            if frame_result.status == FrameStatus.HELD and reasons and not coasted:  # why the pose was held
                run.held_reasons[reasons[0]] = run.held_reasons.get(reasons[0], 0) + 1
            for sink in sinks:
                sink(frame, frame_result)
        completed = True
    finally:
        if isinstance(engine, MapTracking):  # the map's refined poses replace the tracking-time ones (kept)
            run.tracked_poses[:] = run.poses
            run.poses[:] = engine.refined_poses(len(run.poses), adjust=completed)
            run.loops_at_end[:] = engine.loops_at_end
            run.adjusted_at_end = engine.adjusted_at_end
            run.sideways = engine.sideways
            run.placed_at_map_start = engine.before_map.placed
        if completed and finish is not None:
            finish(engine)
        engine.close()
        run.seconds = time.perf_counter() - start
    return run
