"""Names a package exports but loads on first use (PEP 562), so importing the package stays cheap."""

from __future__ import annotations

from collections.abc import Callable, Mapping
from importlib import import_module
from typing import Any


def lazy_names(package: str, homes: Mapping[str, str]) -> Callable[[str], Any]:
    """The module-level ``__getattr__`` of `package`: each name of `homes` (name -> submodule) is imported
    from ``package.submodule`` when first asked for; any other name is an AttributeError."""

    def __getattr__(name: str) -> Any:  # noqa: N807 (it is the module's __getattr__)
        if name not in homes:
            raise AttributeError(f"module {package!r} has no attribute {name!r}")
        return getattr(import_module(f"{package}.{homes[name]}"), name)

    return __getattr__
