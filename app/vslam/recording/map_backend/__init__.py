"""The map backend's entities (`--backend map`): keyframes, landmarks, tracking against the map, bundle adjustment
(`map`), the local-map search and landmark lifetimes (`local_map`), loop closing (`loops`). The odometry backend
writes none of them."""

from vslam.recording.map_backend.map import MapRecording

__all__ = ["MapRecording"]
