"""Names a package imports on first use, so that its light parts never pull in the heavy."""

from __future__ import annotations

import importlib
from collections.abc import Mapping


def imported(package: str, modules: Mapping[str, str], name: str) -> object:
    """``name`` of ``package``, imported from its module when it is first asked for.

    A package whose names bring heavy imports of their own (Zenoh, pyarrow) lists them in
    ``modules`` and returns this from its module ``__getattr__`` (PEP 562), so that
    importing the package costs only what its light names need.

    Args:
        package: The package's ``__name__``.
        modules: Each such name's module: relative to the package (``.codec``) or whole
            (``bridge.export.tables``).
        name: The attribute asked for.

    Raises:
        AttributeError: ``name`` is not one of ``modules``: the package has no such name.
    """
    module = modules.get(name)
    if module is None:
        raise AttributeError(f"module {package!r} has no attribute {name!r}")
    return getattr(importlib.import_module(module, package), name)
