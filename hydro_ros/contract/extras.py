"""Python libraries without a rosdep key (package.xml says which): imported where a tool needs them."""

from __future__ import annotations

import importlib
from types import ModuleType

from hydro_ros.contract.errors import InputError

# import name -> (pip distribution, what needs it)
OPTIONAL = {
    "SALib": ("SALib", "hydro-ros gsa (Sobol indices)"),
    "casadi": ("casadi", "hydro-ros dp compare (the direct-collocation baseline)"),
    "distributed": ("distributed", "hydro-ros db build and fleet analyse --scheduler, make bench --dask (a Dask cluster)"),
    "mcap": ("mcap", "reading bags with the mcap library"),
    "foxglove": ("foxglove-sdk", "the live Foxglove server"),
}


def optional_module(name: str) -> ModuleType:
    """``importlib.import_module(name)``, or a one-line InputError saying what needs it and how to install it."""
    top = name.split(".")[0]
    try:
        return importlib.import_module(name)
    except ImportError:
        distribution, user = OPTIONAL[top]
        raise InputError(f"{user} needs the optional Python package {distribution}: pip install {distribution}") from None
