"""``python -m vslam.cli``: the same as the `vslam` console script."""

from vslam.cli import main

main()
