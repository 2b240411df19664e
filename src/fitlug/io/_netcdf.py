"""posterior.nc: MCMC draws as an ArviZ-layout netCDF-4 file, written with h5netcdf.

The file holds what ``arviz.InferenceData.to_netcdf(path, engine="h5netcdf")`` writes for
an InferenceData made by ``arviz.from_dict(posterior=..., sample_stats=..., attrs=...)``:
one netCDF group per InferenceData group (``posterior``, ``sample_stats``), each with the
dimensions ``chain`` and ``draw``, their integer coordinates, one float64 variable
(chain, draw) per quantity (fill value NaN, as xarray encodes floats), a ``created_at``
attribute per group, and the caller's attributes on the root. ``arviz.from_netcdf`` and
``xarray.open_dataset(path, group=...)`` read it back.

Why not ArviZ itself: importing ArviZ (with xarray, pandas and scipy.stats, which its
plotting module imports) costs ~0.8 s CPU, a tenth of a whole default run of the bundled
recording (issue 43), to write one small file of plain arrays; h5netcdf (ArviZ's own
engine here) writes the same file after an import of ~40 ms. The layout is checked
against ArviZ's in tests/test_netcdf.py.
"""

from __future__ import annotations

import datetime
import os

import numpy as np

from ._atomic import atomic_path


def write_samples_netcdf(path: str | os.PathLike, groups: dict, attrs: dict | None = None) -> None:
    """Write draws to `path` (atomically) in ArviZ's netCDF layout.

    Args:
        path: the file to write (a temporary file beside it is renamed onto it).
        groups: group name -> {variable name -> array (chain, draw)}; every array of a
            group has the same shape.
        attrs: the root's attributes (str, int, float or bool values; bools as 0/1).

    Raises:
        ValueError: an array that is not 2-D or a group whose arrays differ in shape.
    """
    import h5netcdf

    shapes = {}
    for g, data in groups.items():
        arrays = {k: np.asarray(v, dtype=float) for k, v in data.items()}
        dims = {a.shape for a in arrays.values()}
        if len(dims) != 1 or len(next(iter(dims))) != 2:
            raise ValueError(f"group {g!r}: every variable must be one (chain, draw) array; "
                             f"got shapes {sorted(dims)}")
        shapes[g] = (next(iter(dims)), arrays)
    with atomic_path(path, suffix=".nc") as tmp:
        with h5netcdf.File(tmp, "w") as f:
            for k, v in (attrs or {}).items():
                f.attrs[k] = _attr(v)
            for g, ((n_chain, n_draw), arrays) in shapes.items():
                grp = f.create_group(g)
                grp.dimensions = {"chain": n_chain, "draw": n_draw}
                grp.create_variable("chain", ("chain",), data=np.arange(n_chain, dtype=np.int64))
                grp.create_variable("draw", ("draw",), data=np.arange(n_draw, dtype=np.int64))
                for k, a in arrays.items():
                    grp.create_variable(k, ("chain", "draw"), data=a, fillvalue=np.nan)
                grp.attrs["created_at"] = datetime.datetime.now(
                    datetime.timezone.utc).isoformat()


def _attr(v):
    """A netCDF attribute value: strings as they are, numbers as 1-element arrays (as
    xarray writes them)."""
    if isinstance(v, str):
        return v
    if isinstance(v, (bool, np.bool_)):
        return np.array([int(v)])
    if isinstance(v, (int, np.integer, float, np.floating)):
        return np.array([v])
    raise TypeError(f"netCDF attribute of type {type(v).__name__}: {v!r}")
