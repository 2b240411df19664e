"""report.html in a real browser: headless Chromium, at 800 and 1600 px.

Fails on a broken image, a script or console error, an image without alt text, or a page
wider than the window. The page is rendered from a copy of the committed reference fit
(fits/reference: fit.json, state.npz, posterior.nc), once as it is and once with the
keys other stages add (not_identifiable, markers/joined, glitches, systematics,
provenance, drawbar pull, ground) and an explained/unexplained discrepancy block, so every
branch of the headline and the discrepancy section is drawn. matplotlib's layout warnings
are errors here: a figure whose text cannot be laid out must not pass.
"""

import copy
import json
import os
import shutil
import sys

import pytest

sys.path.insert(0, os.path.dirname(__file__))
import browser  # noqa: E402

from fitlug.report import write_report  # noqa: E402

REF = os.path.join(os.path.dirname(__file__), "..", "fits", "reference")

pytestmark = [
    pytest.mark.filterwarnings("error:.*layout.*:UserWarning"),
    pytest.mark.filterwarnings("error:.*Tight layout.*"),
    pytest.mark.filterwarnings("error:.*constrained_layout.*"),
    pytest.mark.skipif(browser.chromium() is None,
                       reason="chromium is not installed (.ci/run installs Debian's "
                              "`chromium` package; it could not be installed here)"),
]


def _copy_reference(dst):
    for name in ("fit.json", "state.npz", "posterior.nc"):
        src = os.path.join(REF, name)
        if os.path.isfile(src):
            shutil.copy(src, dst / name)
    return json.loads((dst / "fit.json").read_text())


def _with_other_stages(doc):
    """The fit.json keys other stages write, as they would write them."""
    d = copy.deepcopy(doc)
    d["stiffness_N_per_mm"] = None
    d["not_identifiable"] = {"stiffness_N_per_mm": "no mass in rig.toml: only k/m is measured"}
    d["rig"] = dict(d.get("rig") or {}, mass_kg=None, drawbar_pull_N=8.0, ground_name="sand")
    d["provenance"] = {"input_sha256": "ab" * 32, "rig_sha256": "cd" * 32,
                       "fitlug_version": d.get("fitlug_version"),
                       "command": "fit-lug data/reference/trajectories.csv --seed 0"}
    d["date_utc"] = "2026-11-22 20:00 UTC"
    d["markers"] = [{"id": "L01", "role": "lug", "ids": ["L01", "L13"], "n_samples": 900,
                     "coverage": 0.71, "t_range_s": [0.0, 6.4]}]
    d["joined"] = [{"marker": "L01", "ids": ["L01", "L13"], "reason": "same lug, 0.02 s gap"}]
    d["glitches"] = [{"marker": "L01", "time_s": 2.5, "dx_mm": 0.3, "dy_mm": -0.1,
                      "size_sigma": 45.0}]
    d["glitch_rule"] = "|r| > 8 sigma after the fit"
    disc = d.get("discrepancy") or {}
    disc["systematics"] = {"amplitude_um": 0.4, "share_of_misfit": 0.6, "slip_effect": 1e-6,
                           "note": "below the tracker floor"}
    d["discrepancy"] = disc
    return d


def _unexplained(doc):
    d = copy.deepcopy(doc)
    disc = d["discrepancy"]
    disc["verdict"] = "unexplained"
    disc["slip_after_uncertainty"] = "cluster-robust sandwich by marker (3.1 x least squares)"
    disc["located"] = [
        {"markers": ["L01", "L02"], "axis": "y", "segment": "top", "phase": "cruise",
         "frequency_hz": 3.3, "t_range_s": [1.0, 5.0], "share_of_misfit": 0.62},
        {"markers": ["L01"], "axis": "y", "segment": "top", "frequency_hz": 3.3,
         "t_range_s": [0.0, 6.0], "share_of_misfit": 0.9, "test": "spectral line",
         "p_value": 1e-9}]
    disc["candidates"] = [{"round": 1, "tried": [
        {"id": "belt_sag", "delta_bic_linear": -50.0, "delta_bic": -40.0,
         "misfit_removed_share": 0.05,
         "rejected_because": "removes 5 % of the excess chi2 (needs 30 %)"},
        {"id": "wheel_runout", "delta_bic_linear": -30.0, "delta_bic": None},
        {"id": "lug_ripple", "delta_bic_linear": 12.0, "delta_bic": None}]}]
    return d


def _explained(doc):
    d = copy.deepcopy(doc)
    disc = d["discrepancy"]
    disc["verdict"] = "explained"
    disc["effects"] = [{"id": "belt_sag", "params": {"sag_d": 0.4912, "sag_x": None},
                        "params_std": {"sag_d": 0.0031}, "not_identifiable":
                            {"sag_x": "the top run is never seen"},
                        "delta_bic": -72765000.0, "chi2_per_dof_before": 480.2,
                        "chi2_per_dof_after": 1.003, "meaning": "the top run sags"}]
    disc["slip_before"] = {"value": 0.0790, "std": 0.0000025, "ci95": [0.07895, 0.07905]}
    d["least_squares"] = dict(d["least_squares"], effects=["belt_sag"])
    return d


def _render(tmp_path, name, edit):
    folder = tmp_path / name
    folder.mkdir()
    doc = _copy_reference(folder)
    (folder / "fit.json").write_text(json.dumps(edit(doc)))
    return write_report(folder)


@pytest.fixture(scope="module")
def pages(tmp_path_factory):
    if not os.path.isfile(os.path.join(REF, "state.npz")):
        pytest.skip("fits/reference/state.npz is missing")
    tmp = tmp_path_factory.mktemp("browser")
    return {"reference": _render(tmp, "reference", lambda d: d),
            "other stages, unexplained": _render(
                tmp, "unexplained", lambda d: _unexplained(_with_other_stages(d))),
            "explained": _render(tmp, "explained", _explained)}


@pytest.mark.parametrize("width", [800, 1600])
def test_report_renders_cleanly_in_chromium(pages, width):
    for what, page in pages.items():
        got = browser.probe(page, width=width)
        assert got["errors"] == [] and got["console"] == [], (what, got)
        assert got["images"] >= 8, (what, got)
        assert got["broken"] == [], (what, got)
        assert got["noalt"] == 0, (what, got)
        assert got["scroll"] <= got["inner"], (what, width, got)


def test_other_stages_keys_are_rendered(pages):
    page = open(pages["other stages, unexplained"], encoding="utf-8").read()
    assert "not identifiable: no mass in rig.toml" in page
    assert "drawbar pull 8 N" in page and "ground: sand" in page
    assert "fit-lug data/reference/trajectories.csv --seed 0" in page
    assert "L01 ← L01, L13" in page and "45.0 σ" in page
    assert "tracker-systematics floor" in page
    # unexplained: a warning box that says where and that the error bar includes it
    assert 'class="verdict v-unexplained"' in page and "includes" in page
    assert "top" in page and "3.3 Hz" in page
    # spectral-line rows are apart from the shares; every candidate has a real reason
    assert "Separate tests (not shares)" in page
    assert "only the 4 most promising" in page and "not below -10" in page
    assert "no score" not in page


def test_explained_headline_says_how_far_the_base_model_was_off(pages):
    page = open(pages["explained"], encoding="utf-8").read()
    head = page[:page.index('<nav class="toc"')]
    assert "Explained" in head and "belt_sag" in head
    assert "2.4 %" in head and "σ off" in head  # 0.0790 vs 0.07716 +- 2.1e-6
    assert "sag_x = not identifiable (the top run is never seen)" in page
    assert "-7.28 × 10⁷" in page  # no "-7.2765e+07"


def test_screenshots(pages, tmp_path):
    """Screenshots at 800 and 1600 px (kept under $FITLUG_SHOTS when set, to look at)."""
    keep = os.environ.get("FITLUG_SHOTS")
    for width in (800, 1600):
        png = browser.screenshot(pages["reference"], str(tmp_path / f"r{width}.png"),
                                 width=width, height=1800)
        assert os.path.getsize(png) > 10000
        if keep:
            os.makedirs(keep, exist_ok=True)
            shutil.copy(png, os.path.join(keep, f"reference_{width}.png"))
