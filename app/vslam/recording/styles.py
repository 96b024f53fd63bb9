"""The colours and legends shared by the entities, the plots and the blueprint (the detail levels: `levels`)."""

from __future__ import annotations

from vslam_core.results import TrackFate

APPLICATION_ID = "vslam"


# Legend of the flow arrows: one annotation context, so the viewer explains the colours.
FATE_STYLE: dict[TrackFate, tuple[str, tuple[int, int, int]]] = {
    TrackFate.LOST: ("lost (KLT failed / left image)", (120, 120, 120)),
    TrackFate.FB_REJECTED: ("rejected by forward–backward check", (255, 140, 0)),
    TrackFate.NOT_USED: ("tracked, no keyframe position yet", (80, 160, 255)),
    TrackFate.RANSAC_OUTLIER: ("RANSAC outlier", (230, 30, 30)),
    TrackFate.CHIRALITY_FAILED: ("failed chirality (behind a camera)", (200, 0, 200)),
    TrackFate.INLIER: ("inlier", (40, 220, 60)),
}
NEW_CORNER_COLOUR = (255, 230, 0)
CANDIDATE_COLOURS = [(255, 200, 0), (0, 200, 255), (255, 0, 160), (160, 255, 0)]
ROAD_COLOUR = (255, 120, 220)
AXIS_COLOURS = [(255, 60, 60), (60, 255, 60), (60, 120, 255)]  # x, y, z of each candidate's camera
CAR_COLOUR = (230, 230, 230)
ESTIMATE_COLOUR = (255, 80, 80)
#: Blue: no error colour map uses it (drift: green -> yellow -> red; health: green, yellow, red).
GROUND_TRUTH_COLOUR = (70, 130, 255)
#: The drive overview's marks: the worst stretches and closed loops (failed frames: the health's red).
WORST_MARK_COLOUR = (255, 255, 255)
LOOP_MARK_COLOUR = (200, 0, 200)

#: A static Markdown text beside the frame view: what each overlay colour means (`overlay_legend`).
LEGEND_ENTITY = "/legend"
#: Names of the overlay colours, for the legend (Markdown cannot colour text).
COLOUR_NAMES = {(120, 120, 120): "grey", (255, 140, 0): "orange", (80, 160, 255): "blue", (230, 30, 30): "red",
                (200, 0, 200): "magenta", (40, 220, 60): "green", NEW_CORNER_COLOUR: "yellow", ROAD_COLOUR: "pink"}
#: Where the health plot's level lines go (not under /metrics/health: `vslam inspect` reads that group).
HEALTH_LEVELS_ROOT = "/metrics/health_levels"
#: The constant lines naming the health plot's levels: (entity name, legend, value, colour).
HEALTH_LEVEL_LINES = (("ok", "0 = ok", 0.0, (40, 220, 60)), ("warn", "1 = warn", 1.0, (255, 200, 0)),
                      ("fail", "2 = fail", 2.0, (230, 30, 30)))


def overlay_legend(road: bool) -> str:
    """Markdown: the frame view's overlays by colour — the flow arrows by track fate (`FATE_STYLE`), the new
    corners and, with `road` (``--scale height``), the road points."""
    lines = ["**Overlays**", "", "Arrows: previous → current position of a track", ""]
    lines += [f"- {COLOUR_NAMES[colour]}: {label}" for fate, (label, colour) in FATE_STYLE.items()
              if fate != TrackFate.LOST]
    lines += ["", f"- {COLOUR_NAMES[NEW_CORNER_COLOUR]} dots: new corners (detected this frame)"]
    if road:
        lines.append(f"- {COLOUR_NAMES[ROAD_COLOUR]} dots: road points (camera height)")
    return "\n".join(lines)
