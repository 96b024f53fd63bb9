"""The default layout embedded in every recording."""

from __future__ import annotations

import rerun as rr
import rerun.blueprint as rrb

from app.recording.metrics import BA_ERROR_SERIES, MAP_METRICS

#: Entities of the map backend that keep their whole past in the 3-D view (logged once each, they accumulate).
MAP_WHOLE_PAST = ("/world/map/keyframes/retired", "/world/map/landmarks/retired")


def blueprint(map_backend: bool = False) -> rrb.Blueprint:
    """Frame with overlays | 3-D world with trajectories and candidates | metric plots and events.

    `map_backend`: also the map (retired keyframes and landmarks keep their whole past) and the plots of the
    tracking mode and bundle adjustment. Without it the layout is exactly the odometry backend's."""
    whole_past = rr.VisibleTimeRange(
        "frame", start=rr.TimeRangeBoundary.infinite(), end=rr.TimeRangeBoundary.cursor_relative()
    )
    # the trajectories keep their whole past; everything else shows the current frame
    overrides = {
        "/world/trajectory/estimate": rrb.VisibleTimeRanges([whole_past]),
        "/world/trajectory/ground_truth": rrb.VisibleTimeRanges([whole_past]),
    }
    if map_backend:
        overrides.update({entity: rrb.VisibleTimeRanges([whole_past]) for entity in MAP_WHOLE_PAST})
    return rrb.Blueprint(
        rrb.Horizontal(
            rrb.Vertical(
                rrb.Spatial2DView(name="frame", origin="/world/camera/image"),
                rrb.Spatial3DView(
                    name="world",
                    origin="/world",
                    # follow the car from behind and above (RDF: −y is up, −z is behind)
                    eye_controls=rrb.EyeControls3D(kind=rrb.Eye3DKind.Orbital, eye_up=[0.0, -1.0, 0.0],
                                                   tracking_entity="/world/camera"),
                    overrides=overrides,  # type: ignore[arg-type]
                ),
                row_shares=[1, 2],
            ),
            rrb.Vertical(
                rrb.Grid(
                    rrb.TimeSeriesView(name="tracks", origin="/metrics/tracks"),
                    rrb.TimeSeriesView(name="inliers", origin="/metrics/ransac"),
                    rrb.TimeSeriesView(name="inlier ratio", origin="/metrics/ratio"),
                    rrb.TimeSeriesView(name="health", origin="/metrics/health"),
                    rrb.TimeSeriesView(name="motion", origin="/metrics/motion"),
                    rrb.TimeSeriesView(name="scale from the road", origin="/metrics/road"),
                    rrb.TimeSeriesView(name="position error (m)", origin="/metrics/error"),
                    rrb.TimeSeriesView(name="angle errors (°)", origin="/metrics/angle_error"),
                    rrb.TimeSeriesView(name="timing (ms)", origin="/metrics/timing_ms"),
                    *(_map_plots() if map_backend else []),
                    rrb.TextLogView(name="events", origin="/events"),
                    rrb.TextDocumentView(name="report", origin="/report"),
                    grid_columns=2,
                ),
            ),
            column_shares=[3, 2],
        ),
        collapse_panels=True,
    )


def _map_plots() -> list[rrb.TimeSeriesView]:
    """Tracking mode | landmarks tracked and PnP inliers | BA reprojection errors | the rest of each BA run."""
    work = [f"/metrics/ba/{name}" for name in MAP_METRICS["ba"] if name not in BA_ERROR_SERIES]
    return [
        rrb.TimeSeriesView(name="tracking mode", origin="/metrics/tracking", contents=["/metrics/tracking/mode"]),
        rrb.TimeSeriesView(name="landmarks tracked", origin="/metrics/tracking",
                           contents=["/metrics/tracking/pnp_inliers", "/metrics/tracking/landmarks_tracked"]),
        rrb.TimeSeriesView(name="bundle adjustment error (px)", origin="/metrics/ba",
                           contents=[f"/metrics/ba/{name}" for name in BA_ERROR_SERIES]),
        rrb.TimeSeriesView(name="bundle adjustment", origin="/metrics/ba", contents=work),
    ]
