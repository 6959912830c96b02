"""A package's public API imported on first use (PEP 562 module ``__getattr__``/``__dir__``).

``__getattr__, __dir__ = lazy_api(__name__, EXPORTS)`` in a package's ``__init__``, with
``EXPORTS`` mapping each public name to the package's module that defines it (relative).
"""

from __future__ import annotations

from importlib import import_module
import sys
from typing import Callable, Mapping


def lazy_api(package: str, exports: Mapping[str, str]
             ) -> tuple[Callable[[str], object], Callable[[], list[str]]]:
    """Return the package's ``__getattr__`` and ``__dir__`` for ``exports`` (name: module)."""
    def __getattr__(name: str) -> object:
        try:
            module = exports[name]
        except KeyError:
            raise AttributeError(f'module {package!r} has no attribute {name!r}') from None
        value = getattr(import_module(f'{package}.{module}'), name)
        setattr(sys.modules[package], name, value)
        return value

    def __dir__() -> list[str]:
        return sorted(set(vars(sys.modules[package])) | set(exports))

    return __getattr__, __dir__
