"""Figures of library results, on your axes: each function takes a result object and
``ax=`` (a new figure when None), draws with its legend inside the axes and returns the
axes (``corner`` takes and returns a figure: it draws a grid of axes).

- :func:`residuals`: data minus model per marker over time (raw mm or standardised);
- :func:`trajectories`: the markers' data against the fitted model;
- :func:`slip`: the slip s(t) with its 95 % band (from the covariance);
- :func:`posterior`: one sampled quantity's histogram with its median and interval;
- :func:`corner`: the posterior's pairs (corner.py).

matplotlib is imported when a function is called, never by ``import fitlug``.
"""

from ._fit_plots import residuals as residuals, slip as slip, trajectories as trajectories
from ._posterior_plots import corner as corner, posterior as posterior
