"""pandas kept out of vslam's processes: pyarrow (under rerun and polars) imports it, when it is installed (evo,
in the dev extra, brings it), the first time it converts a Python list or scalar, only to recognise pandas
objects among its inputs: ~0.3 s of CPU, a quarter of a short run's start-up. vslam never uses pandas nor hands
pyarrow a pandas object; without pandas pyarrow converts the same values the same way, except Arrow's nanosecond
times to Python values (vslam reads them as numbers, or not at all: `vslam.rrd.read.blueprint_view_names`).
pyarrow, once it found no pandas, takes it as absent for the rest of the process (after an in-process command too),
but for the pandas conversions themselves, which import it when asked."""

from __future__ import annotations

import contextlib
import importlib.abc
import sys
from collections.abc import Iterator, Sequence
from types import ModuleType


class _NoPandas(importlib.abc.MetaPathFinder):
    """An import of pandas fails at once, as if it were not installed."""

    def find_spec(self, fullname: str, path: Sequence[str] | None,
                  target: ModuleType | None = None) -> None:
        if fullname == "pandas" or fullname.startswith("pandas."):
            raise ModuleNotFoundError(f"No module named {fullname!r} (left out by vslam)", name=fullname)
        return None


@contextlib.contextmanager
def pandas_left_out() -> Iterator[None]:
    """pandas cannot be imported inside the block (unless it is imported already): a `vslam` command."""
    finder = _NoPandas()
    sys.meta_path.insert(0, finder)
    try:
        yield
    finally:
        sys.meta_path.remove(finder)


def leave_out_pandas() -> None:
    """pandas cannot be imported in this process from now on (a batch worker's, the pool's `initializer`)."""
    sys.meta_path.insert(0, _NoPandas())
