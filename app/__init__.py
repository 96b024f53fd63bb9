"""The `vslam` application (CLI, recordings, viewer, reports).

Importing it first quiets FFmpeg and OpenCV, before anything imports cv2: they read these variables when
they start, and their log lines (e.g. FFmpeg's "moov atom not found" for a truncated video) would precede
vslam's own one-line error. Values already set in the environment win.
"""

import os

os.environ.setdefault("OPENCV_LOG_LEVEL", "SILENT")
os.environ.setdefault("OPENCV_FFMPEG_LOGLEVEL", "-8")  # AV_LOG_QUIET
