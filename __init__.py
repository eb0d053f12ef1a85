"""fgins: GNSS/INS factor-graph smoothing (GTSAM) with Kalman-filter baselines.

The public API (see :mod:`fgins.api` and the README's "Python API")::

    import fgins
    dataset = fgins.load("demo:kitti")                          # -> Dataset
    track = fgins.smooth(dataset, "batch", gnss_outage=[(60, 90)])  # -> Trajectory
    track.write("track.tum"); frame = track.to_dataframe(); track.summary()
    table = fgins.bench(dataset, methods=["batch", "ekf"])       # -> pandas.DataFrame

Names are resolved on first use (module ``__getattr__``), so ``import fgins`` imports
neither numpy nor GTSAM nor matplotlib.
"""

from __future__ import annotations

import importlib

# Not typing.TYPE_CHECKING: importing typing would cost more than the rest of this module
# (type checkers treat a module-level TYPE_CHECKING = False the same way).
TYPE_CHECKING = False

__version__ = "0.1.0"

# Public name -> module that defines it.
_EXPORTS = {
    "load": "fgins.api",
    "smooth": "fgins.api",
    "bench": "fgins.bench",  # the subpackage, callable: fgins.bench(...) is fgins.api.bench
    "plot": "fgins.api",
    "simulate": "fgins.api",
    "configure": "fgins.api",
    "write": "fgins.api",
    "check_output": "fgins.api",
    "FginsWarning": "fgins.api",
    "FginsError": "fgins.datatypes",
    "InputError": "fgins.datatypes",
    "ConfigError": "fgins.datatypes",
    "OutputError": "fgins.datatypes",
    "Dataset": "fgins.datatypes",
    "Trajectory": "fgins.datatypes",
    "ImuData": "fgins.datatypes",
    "GnssData": "fgins.datatypes",
    "BaroData": "fgins.datatypes",
    "OdometerData": "fgins.datatypes",
    "Origin": "fgins.datatypes",
    "RunConfig": "fgins.config",
}

__all__ = [
    "BaroData",
    "ConfigError",
    "Dataset",
    "FginsError",
    "FginsWarning",
    "GnssData",
    "ImuData",
    "InputError",
    "OdometerData",
    "Origin",
    "OutputError",
    "RunConfig",
    "Trajectory",
    "__version__",
    "bench",
    "check_output",
    "configure",
    "load",
    "plot",
    "simulate",
    "smooth",
    "write",
]

if TYPE_CHECKING:  # for type checkers and IDEs; at run time __getattr__ does this lazily
    from fgins import bench
    from fgins.api import (
        FginsWarning,
        check_output,
        configure,
        load,
        plot,
        simulate,
        smooth,
        write,
    )
    from fgins.config import RunConfig
    from fgins.datatypes import (
        BaroData,
        ConfigError,
        Dataset,
        FginsError,
        GnssData,
        ImuData,
        InputError,
        OdometerData,
        Origin,
        OutputError,
        Trajectory,
    )


def __getattr__(name: str) -> object:
    module = _EXPORTS.get(name)
    if module is None:
        raise AttributeError(f"module 'fgins' has no attribute {name!r}")
    imported = importlib.import_module(module)
    value = imported if module == f"fgins.{name}" else getattr(imported, name)
    globals()[name] = value  # resolve once
    return value


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(_EXPORTS))
