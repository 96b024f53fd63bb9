"""The synthetic street, the embedded default data source (see `street`)."""

from vslam_core.sources.synthetic.street import SyntheticStreet

__all__ = ["SyntheticStreet"]
