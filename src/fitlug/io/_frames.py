"""A Recording as a pandas DataFrame (DATA.md's long form), for notebooks."""

from __future__ import annotations


def recording_to_dataframe(rec):
    """See :meth:`Recording.to_dataframe`."""
    import numpy as np
    import pandas as pd

    idx = np.asarray(rec.marker_index)
    cols = {"time_s": np.asarray(rec.t, float),
            "marker": np.asarray(rec.markers, dtype=object)[idx],
            "role": np.asarray(rec.roles, dtype=object)[idx],
            "x_mm": np.asarray(rec.x, float), "y_mm": np.asarray(rec.y, float)}
    for name, attr in (("sigma_mm", "sigma"), ("frame", "frame"), ("x_px", "x_px"),
                       ("y_px", "y_px"), ("quality", "quality")):
        value = getattr(rec, attr)
        if value is not None:
            cols[name] = np.asarray(value)
    return pd.DataFrame(cols)
