"""``python -m vslam``: the same as the `vslam` console script."""

from vslam.cli import main

main()
