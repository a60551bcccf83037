"""Package facades whose names load on first use, so that a command starts without the heavy
modules behind them (numpy, h5py, the solver)."""

from __future__ import annotations

import importlib
from typing import Callable


def lazy_exports(package: str, exports: dict[str, tuple[str, ...]], namespace: dict
                 ) -> tuple[list[str], dict[str, str], Callable, Callable]:
    """A facade for `package`: `exports` maps each module to the names it gives the package.

    Returns `__all__` (sorted names), the name -> module map, and the package's `__getattr__`
    (imports a name's module when the name is first asked for, then keeps the value in
    `namespace`, the package's globals) and `__dir__`.
    """
    home = {name: module for module, names in exports.items() for name in names}

    def __getattr__(name: str):
        module = home.get(name)
        if module is None:
            raise AttributeError(f"module {package!r} has no attribute {name!r}")
        value = getattr(importlib.import_module(module), name)
        namespace[name] = value
        return value

    def __dir__() -> list[str]:
        return sorted(set(namespace) | set(home))

    return sorted(home), home, __getattr__, __dir__
