"""Outage benchmark: protocol, metrics, tables, plots -- and, called, ``fgins.bench()``.

``fgins.bench(dataset, methods=..., outages=...)`` is :func:`fgins.api.bench` (see its help
for parameters and units). The public function and this subpackage share the name
``fgins.bench``, and Python sets the package as that attribute once any ``fgins.bench.*``
module is imported, so the package itself is callable and forwards to the function: both
spellings stay one thing.
"""

from __future__ import annotations

import sys
import types


class _CallablePackage(types.ModuleType):
    def __call__(self, *args, **kwargs):
        from fgins.api import bench

        return bench(*args, **kwargs)

    @property
    def __signature__(self):  # inspect.signature / IDEs: the function's parameters
        import inspect

        from fgins.api import bench

        return inspect.signature(bench)


sys.modules[__name__].__class__ = _CallablePackage
