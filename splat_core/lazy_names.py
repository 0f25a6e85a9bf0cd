"""A package's names imported on first use (PEP 562), so that importing one of its torch-free
modules does not import the rest: splat_core.io, splat_core.run.

    __getattr__, __dir__ = lazy_names(__name__, {"Pipeline": "pipeline", ...})
"""

from __future__ import annotations

from importlib import import_module


def lazy_names(package: str, homes: dict[str, str]):
    """(__getattr__, __dir__) for `package`: each name in `homes` is taken from its module (relative
    to the package) when first asked for."""
    def __getattr__(name: str):
        if name not in homes:
            raise AttributeError(f"module {package!r} has no attribute {name!r}")
        return getattr(import_module(f".{homes[name]}", package), name)

    def __dir__():
        return sorted(set(vars(import_module(package))) | set(homes))

    return __getattr__, __dir__
