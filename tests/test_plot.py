"""fitlug.plot (issue 27, item 7): public plots of result objects on the caller's axes,
returning them, legends inside the axes. What is drawn is checked against numbers the plot
did not make: the recording's own samples minus the model, FitResult.slip_at's band, the
posterior's samples (the posterior plots are tested on test_identifiable's posterior,
sampled once for both)."""

from __future__ import annotations

import matplotlib

matplotlib.use("Agg")

import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import pytest  # noqa: E402

import fitlug  # noqa: E402
from fitlug import plot  # noqa: E402
from fitlug.sim import Scenario, rig_of, simulate  # noqa: E402

SC = Scenario(duration_s=1.5, travel_mm=150, rest_s=0.2, ramp_s=0.4)  # test_predict's


@pytest.fixture(scope="module")
def fitted():
    rec, _ = simulate(SC, 5)
    return fitlug.fit(rec, rig_of(SC))


def legend_inside(ax):
    """Whether ax's legend lies inside ax (drawn)."""
    return _legend_inside(ax)


def _legend_inside(ax):
    fig = ax.figure
    fig.canvas.draw()
    r = fig.canvas.get_renderer()
    lb, ab = ax.get_legend().get_window_extent(r), ax.get_window_extent(r)
    return (lb.x0 >= ab.x0 - 1 and lb.x1 <= ab.x1 + 1 and lb.y0 >= ab.y0 - 1
            and lb.y1 <= ab.y1 + 1)


def test_residuals_per_marker_are_data_minus_model_on_my_axes(fitted):
    fig, (a1, a2) = plt.subplots(1, 2, figsize=(10, 3))
    assert plot.residuals(fitted, ax=a1, markers=["B02", "C1"]) is a1
    assert plot.residuals(fitted, ax=a2, axis="y", standardised=True) is a2
    lines = {ln.get_label(): ln for ln in a1.get_lines() if not ln.get_label().startswith("_")}
    assert set(lines) == {"B02", "C1"} and _legend_inside(a1)
    # C1's x residual at its samples: the recording's x minus the model there
    rec = fitted.problem.rec
    sel = rec.marker_index == list(rec.markers).index("C1")
    t, x = rec.t[sel], rec.x[sel]
    model = fitted.predict(t, markers="C1").x[0]
    tt, rr = lines["C1"].get_data()
    np.testing.assert_allclose(rr, np.interp(tt, t, x - model), atol=1e-6)
    assert 0.5 < np.std(np.concatenate([ln.get_ydata() for ln in a2.get_lines()[:-1]])) < 2
    with pytest.raises(ValueError, match="fitted markers: B01"):
        plot.residuals(fitted, ax=a1, markers=["nope"])
    plt.close(fig)


def test_slip_and_trajectories_draw_the_model_and_its_band(fitted):
    ax = plot.slip(fitted)  # a new figure
    assert ax.figure is not None and _legend_inside(ax)
    line = [ln for ln in ax.get_lines() if ln.get_label() == "slip s(t)"][0]
    t, s = line.get_data()
    b = fitted.slip_at(t)
    np.testing.assert_allclose(s, b.value, equal_nan=True)
    moving = np.isfinite(s)
    assert abs(np.nanmedian(s[moving]) - fitted.slip.value) < 1e-3
    fig, ax2 = plt.subplots()
    assert plot.trajectories(fitted, ax=ax2, markers=["C1", "B01"]) is ax2
    assert _legend_inside(ax2)
    plt.close("all")


def test_close_spectral_lines_share_one_label():
    """Lines closer than 4 % of the frequency axis (before and after, or a cluster below
    2.5 Hz) are labelled once, their frequencies joined; a line apart keeps its own label
    (five labels under 2.5 Hz were drawn over each other on an engine recording)."""
    from fitlug.report._discrepancy_plots import plot_spectra

    f = np.linspace(0.0, 50.0, 501)
    def power(lines):
        p = np.ones_like(f)
        for f0, a in lines:
            p += a * np.exp(-0.5 * ((f - f0) / 0.05) ** 2)
        return p
    before = {"f_hz": list(f), "power": list(power([(0.4, 1e4), (0.8, 3e4), (1.5, 2e4),
                                                    (20.0, 5e3)])),
              "lug_passing_hz": 8.0, "wheel_revolution_hz": 1.0}
    after = {"f_hz": list(f), "power": list(power([(0.8, 1e3), (20.0, 5e3)]))}
    fig, peaks = plot_spectra({"before": before, "after": after})
    labels = sorted(t.get_text() for t in fig.axes[0].texts)
    plt.close(fig)
    assert labels == ["0.40, 0.80, 1.50 Hz", "20.00 Hz"], labels
    assert len(peaks) == 6  # every line is still listed for the caption
