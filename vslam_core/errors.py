"""Domain exceptions. The CLI turns every `VslamError` into a one-line message and a non-zero exit."""


class VslamError(Exception):
    """Base of every error vslam reports to a user (never a traceback)."""


class ConfigError(VslamError):
    """A config file or option is malformed: unknown key, wrong type, impossible value."""


class SourceError(VslamError):
    """A data source cannot be read: missing folder, bad calib, unreadable image, bad frame range."""


class TrajectoryFormatError(VslamError):
    """A trajectory / poses file is malformed (names the file and line)."""


class GeometryError(VslamError):
    """Geometric input is invalid (wrong shapes, non-finite values)."""
