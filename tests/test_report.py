"""report.html: one self-contained file with every section, rebuilt by `fit-lug report DIR`."""

import base64
import json
import os
import re

import numpy as np
import pytest

from fitlug import InputError
from fitlug.cli import main
from fitlug.fit import fit
from fitlug.posterior import sample_posterior
from fitlug.io import write_json
from fitlug.report import fit_json, load_state, save_state, write_report
from fitlug.report import _format as fmt
from fitlug.report._section_convergence import plot_trace
from fitlug.report._section_kinematics import plot_displacement, plot_velocity
from fitlug.report._section_least_squares import plot_correlation
from fitlug.report._section_posterior import plot_corner, plot_slip_posterior
from fitlug.report._section_residuals import (plot_residuals_path, plot_residuals_time,
                                              plot_segment_rms)
from fitlug.report._section_slip import (creep, plot_slip_force, plot_slip_time, plot_stall,
                                         slip_from_lugs, stall_window)
from fitlug.report._section_trajectories import plot_trajectories
from fitlug.sim import REFERENCE_SLIP, Scenario, rig_of, simulate

# the reference rig (n = 8, L = 127 mm), a short recording
SC = Scenario(duration_s=3.0, travel_mm=300, rest_s=0.3, ramp_s=0.8, lug_markers=6)
SECTIONS = ("summary", "estimates", "slip", "trajectories", "kinematics", "residuals",
            "least-squares", "posterior", "convergence")

# a figure whose text matplotlib cannot lay out is a defect, not a warning
pytestmark = [pytest.mark.filterwarnings("error:.*layout.*:UserWarning"),
              pytest.mark.filterwarnings("error:.*constrained_layout.*")]


@pytest.fixture(scope="module")
def fitted():
    rec, truth = simulate(SC, 42)
    res = fit(rec, rig_of(SC), noise={"lug": SC.noise_lug_mm, "body": SC.noise_body_mm})
    post = sample_posterior(res, seed=1)
    return res, post, truth


@pytest.fixture(scope="module")
def folder(fitted, tmp_path_factory):
    res, post, _ = fitted
    d = tmp_path_factory.mktemp("fit")
    write_json(d / "fit.json", fit_json(res, input_path="trajectories.csv",
                                        posterior=post.estimates, mcmc=post.mcmc_json()))
    save_state(d, res, posterior=post)
    post.save(d / "posterior.nc")
    write_report(d)
    return d


def _images(page):
    return re.findall(r'<img alt="([^"]*)" src="data:image/png;base64,([^"]+)"', page)


def test_report_is_self_contained_with_every_section(folder):
    page = (folder / "report.html").read_text(encoding="utf-8")
    assert page.startswith("<!DOCTYPE html>") and page.rstrip().endswith("</html>")
    for sid in SECTIONS:
        assert f'<section id="{sid}">' in page, sid
    # nothing loaded from elsewhere: every src is inline data, no stylesheets or scripts
    srcs = re.findall(r'\bsrc\s*=\s*["\']([^"\']*)', page)
    assert srcs and all(s.startswith("data:image/png;base64,") for s in srcs)
    assert not re.search(r"<link\b|<script\b|@import|url\(", page)
    imgs = _images(page)
    alts = " ".join(a for a, _ in imgs)
    for what in ("trajectories", "stall", "displacement and velocity", "residuals",
                 "corner", "slippage posterior", "slip s(t)", "slip against traction force",
                 "per marker", "correlation matrix"):
        assert what in alts, what
    for _, b64 in imgs:
        assert base64.b64decode(b64)[:8] == b"\x89PNG\r\n\x1a\n"
    # every figure has a caption and the page a table of contents linking every section
    assert page.count("<figcaption>") == len(imgs)
    for sid in SECTIONS[1:]:
        assert f'<a href="#{sid}">' in page, sid
    assert [p.name for p in folder.iterdir() if p.name.startswith(".")] == []


def test_report_shows_estimates_and_diagnostics(folder, fitted):
    res, post, _ = fitted
    page = (folder / "report.html").read_text(encoding="utf-8")
    s = post.estimates["slip"]
    # one error everywhere, digits set by it: the headline and the estimates table agree
    pm = fmt.pm(s.value, s.std)
    head = page[:page.index('<nav class="toc"')]
    assert pm in head and page.count(pm) >= 2
    m = post.mcmc_json()
    assert "converged" in page and fmt.sig(m["acceptance"], 3) in page
    assert "R-hat" in page and "MCSE" in page and "linearisation check" in page
    assert "BIC = χ² + k ln N" in page and "solver steps" in page
    assert "Track slip of trajectories" in page or "<title>" in page
    for label in ("lug shear stiffness k", "rolling resistance C<sub>rr</sub>", "lug deflection",
                  "wheel pitch radius R", "noise, lug markers"):
        assert label in page
    # the reference rig: the paper's value is marked, with the distance in sigma
    assert f"Reference paper: s = {REFERENCE_SLIP:g}" in page
    assert fmt.sigma_apart(s.value, s.std, REFERENCE_SLIP) in page


def test_state_holds_what_the_report_draws(folder, fitted):
    res, post, _ = fitted
    st = load_state(folder)
    n = len(np.asarray(res.problem.lay.lug_t))
    assert st["lug_res_x"].shape == (n,) and st["lug_seg"].shape == (n,)
    assert set(np.unique(st["lug_seg"])) == {0, 1, 2, 3}
    # the residuals are data - model, consistent with the fit's weighted residuals
    w = np.asarray(res.problem.obs["lug_w"])
    np.testing.assert_allclose(-st["lug_res_x"][w > 0] * w[w > 0], res.residuals[:n][w > 0],
                               rtol=1e-6, atol=1e-9)
    assert st["post_samples"].shape[1] == len(st["meta"]["post_names"])
    i = st["meta"]["post_names"].index("slip")
    assert np.median(st["post_samples"][:, i]) == pytest.approx(post.estimates["slip"].value,
                                                                rel=1e-6)


def test_state_through_the_exported_module_equals_the_jitted_one(folder, fitted, monkeypatch):
    """The state's model arrays come from a module exported to disk (fitlug._exported): the
    same numbers, bit for bit, as the compiled function itself (the export cache off)."""
    from types import SimpleNamespace

    from fitlug.report._state import state_arrays

    res, _, _ = fitted
    base = SimpleNamespace(base=res)  # the base residuals go through a second module
    a, meta = state_arrays(res, explanation=base)
    monkeypatch.setenv("FITLUG_NO_EXPORT_CACHE", "1")
    b, meta_b = state_arrays(res, explanation=base)
    assert meta == meta_b and set(a) == set(b)
    for k in a:
        np.testing.assert_array_equal(a[k], b[k], err_msg=k)


def test_cli_rebuilds_the_report(folder, capsys):
    os.remove(folder / "report.html")
    assert main(["report", str(folder)]) == 0
    assert (folder / "report.html").is_file()
    assert str(folder / "report.html") in capsys.readouterr().out
    assert main(["report", str(folder / "nowhere")]) == 2


def test_least_squares_only_and_discrepancy_hook(fitted, tmp_path):
    res, _, _ = fitted
    doc = fit_json(res, input_path="trajectories.csv")
    doc["mcmc"] = None
    doc["mcmc_skipped"] = "--no-mcmc"
    write_json(tmp_path / "fit.json", doc)
    save_state(tmp_path, res)
    page = open(write_report(tmp_path), encoding="utf-8").read()
    assert "Posterior not sampled" in page and "--no-mcmc" in page
    assert "No posterior samples" in page and 'id="discrepancy"' not in page
    doc["discrepancy"] = {"verdict": "explained", "located": [], "effects": [
        {"id": "lug_ripple", "params": {"ripple_a": 0.001}, "delta_bic": -120.0,
         "chi2_per_dof_before": 3.2, "chi2_per_dof_after": 1.01}],
        "slip_before": None, "slip_after": None}
    write_json(tmp_path / "fit.json", doc)
    page = open(write_report(tmp_path), encoding="utf-8").read()
    assert "lug_ripple" in page and "explained" in page


def test_residuals_before_an_explanation_are_drawn(fitted, tmp_path):
    from types import SimpleNamespace

    res, post, _ = fitted
    doc = fit_json(res, posterior=post.estimates, mcmc=post.mcmc_json())
    write_json(tmp_path / "fit.json", doc)
    save_state(tmp_path, res, posterior=post, explanation=SimpleNamespace(base=res))
    st = load_state(tmp_path)
    np.testing.assert_array_equal(st["base_lug_res_y"], st["lug_res_y"])
    page = open(write_report(tmp_path), encoding="utf-8").read()
    # nothing was added: no "before" figure repeating the residuals
    assert "residuals before the effects were added" not in page
    doc["discrepancy"] = {"verdict": "explained", "located": [], "effects": [
        {"id": "lug_ripple", "params": {"ripple_a": 0.001}, "delta_bic": -120.0}],
        "slip_before": None, "slip_after": None}
    write_json(tmp_path / "fit.json", doc)
    page = open(write_report(tmp_path), encoding="utf-8").read()
    assert "residuals before the effects were added and after" in page


def test_missing_files_are_named(tmp_path):
    with pytest.raises(InputError, match="fit.json"):
        write_report(tmp_path)
    (tmp_path / "fit.json").write_text(json.dumps({"slip": None}))
    with pytest.raises(InputError, match="state.npz"):
        write_report(tmp_path)


def test_plot_functions_take_an_ax(folder):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    st = load_state(folder)
    names = st["meta"]["post_names"]
    calls = [
        lambda ax: plot_trajectories(st, ax=ax),
        lambda ax: plot_stall(st, ax=ax) and ax,
        lambda ax: plot_slip_time(st, ax=ax),
        lambda ax: plot_slip_force(st, ax=ax),
        lambda ax: plot_correlation(st["lsq_corr"], st["meta"]["corr_names"], ax=ax),
        lambda ax: plot_displacement(st, ax=ax),
        lambda ax: plot_velocity(st, ax=ax),
        lambda ax: plot_residuals_time(st, "y", ax=ax),
        lambda ax: plot_residuals_path(st, "x", ax=ax),
        lambda ax: plot_segment_rms(st, ax=ax),
        lambda ax: plot_slip_posterior(st["post_samples"][:, names.index("slip")],
                                              ax=ax, reference=REFERENCE_SLIP),
        lambda ax: plot_trace(st["post_chain"], ax=ax),
    ]
    for call in calls:
        fig, ax = plt.subplots()
        assert call(ax) is ax
        assert ax.has_data()
        plt.close(fig)
    fig = plt.figure()
    assert plot_corner(st["post_samples"][:, :2], ["a", "b"], fig=fig) is fig
    plt.close(fig)
    # without an ax, each makes its own figure
    ax = plot_displacement(st)
    assert ax.figure is not None
    plt.close(ax.figure)


def test_stall_window_is_a_bottom_run_contact(folder):
    st = load_state(folder)
    m, t0, t1 = stall_window(st)
    sel = (st["lug_i"] == m) & (st["lug_t"] >= t0) & (st["lug_t"] <= t1)
    assert np.all(st["lug_seg"][sel] == 0)
    # on the ground the marker stalls: it drifts rearward at s v_t, far slower than the body
    x = st["lug_x"][sel]
    v_marker = abs(np.polyfit(st["lug_t"][sel], x, 1)[0])
    v_body = np.interp(0.5 * (t0 + t1), st["fine_t"], st["fine_v"])
    assert v_marker < 0.2 * v_body


def test_stall_creep_is_the_slip_times_the_run(folder, fitted):
    """On the ground a lug marker creeps rearward by s D over one contact (MODEL.md: it
    moves at -s v_t for D / v_t); the simulator's truth, not the fit, sets s."""
    _, _, truth = fitted
    st = load_state(folder)
    cr = creep(st)
    assert cr is not None and cr["measured_mm"] > 0
    D = st["meta"]["least_squares"]["D_mm"]["value"]
    s_true = truth["slip"] if isinstance(truth, dict) else truth.slip
    # the contact is seen at a frame rate: up to one frame's travel short at each end
    assert cr["measured_mm"] == pytest.approx(s_true * D, rel=0.1)


def test_slip_from_the_lugs_matches_the_truth(folder, fitted):
    """The slip measured straight from the bottom-run markers (s = -u / (v - u)), at cruise,
    agrees with the simulated steady slip: the point cloud of the slip-force plot is data."""
    _, _, truth = fitted
    st = load_state(folder)
    t, s = slip_from_lugs(st)
    a = np.interp(t, st["fine_t"], np.gradient(st["fine_v"], st["fine_t"]))
    cruise = np.abs(a) < 0.05 * np.max(np.abs(a))
    s_true = truth["slip"] if isinstance(truth, dict) else truth.slip
    assert cruise.sum() >= 20
    assert np.median(s[cruise]) == pytest.approx(s_true, abs=0.01)


@pytest.mark.parametrize("value,std,text", [
    (0.07715779138891603, 2.061656403006902e-06, "0.0771578 ± 0.0000021"),
    (1.3998627866274764, 3.740433759741182e-05, "1.399863 ± 0.000037"),
    (0.1, 0.02, "0.100 ± 0.020"),
    (1234.5, 0.0996, "1234.50 ± 0.10"),      # the error rounds up a digit
    (3.74e-7, 1.2e-9, "(3.740 ± 0.012) × 10⁻⁷"),
    (5.0, None, "5.00000"),
])
def test_value_with_error(value, std, text):
    assert fmt.pm(value, std) == text


def test_intervals_name_their_level_and_never_collapse():
    assert fmt.interval(1.399790152963036, 1.3999355144013452, 3.74e-5) == \
        "95 %: 1.399790 … 1.399936"
    # the ends differ in the 7th digit only: more digits, never "1.4 … 1.4"
    lo, hi = fmt.interval(1.4, 1.4000001, 1e-3, 68).split(": ")[1].split(" … ")
    assert lo != hi and fmt.interval(1, 2, level=68).startswith("68 %: ")
    assert fmt.sig(-7.2765e7, 3) == "-7.28 × 10⁷" and "e+" not in fmt.sig(1e9)
    assert fmt.sigma_apart(0.0771578, 2.06e-6, 0.07716) == "1.1 σ below"
    assert fmt.pm(0.0771578, 2.06e-6, ascii=True) == "0.0771578 +/- 0.0000021"


def test_terminal_summary_digits_and_verdict(capsys):
    """The terminal prints the headline's numbers with the same digits, effect parameters
    and the slip before the explanation (from a fit.json dict; no fit needed)."""
    from types import SimpleNamespace

    from fitlug.cli._fit import _summary

    ref = os.path.join(os.path.dirname(__file__), "..", "fits", "reference", "fit.json")
    doc = json.load(open(ref, encoding="utf-8"))
    doc["discrepancy"] = dict(doc["discrepancy"], verdict="explained", effects=[
        {"id": "belt_sag", "params": {"sag_d": 0.4997}, "params_std": {"sag_d": 0.00033}}],
        slip_before={"value": 0.0770047, "std": 2.1e-6})
    _summary(SimpleNamespace(quiet=False), doc, "out", "out/report.html", 1.0)
    out = capsys.readouterr().out
    s = doc["slip"]
    assert fmt.pm(s["value"], s["std"]) in out and "95 %: " in out
    assert "belt_sag: sag_d = 0.49970 ± 0.00033" in out
    assert "slip without it 0.0770047 ± 0.0000021" in out and "σ below" in out
    assert "e-0" not in out  # no "2.1e-06"


@pytest.mark.parametrize("change, shown", [
    ({}, True),                                                    # the reference rig as given
    ({"rig": {"load_bearing_length_mm": 200.0}}, False),           # another robot: L
    ({"rig": {"lugs_in_contact": 6}}, False),                      # n
    ({"rig": {"lug_pitch_mm": 25.4}}, False),                      # its pitch as given
    ({"rig": {"lug_pitch_mm": None}, "geometry": {"pitch_mm": 18.40}}, True),   # fitted, 0.2 %
    ({"rig": {"lug_pitch_mm": None}, "geometry": {"pitch_mm": 21.0}}, False),   # fitted, 14 %
])
def test_reference_paper_compared_only_on_the_reference_rig(change, shown):
    """Issue 44: "this fit is 110 σ above it" was printed for every rig; the paper's 0.07716
    is set beside the slip only where the rig is the reference study's (n = 8, L = 127 mm,
    pitch 18.36 mm as given, or fitted within 1 % where not given)."""
    from fitlug.report._section_summary import _headline

    ref = os.path.join(os.path.dirname(__file__), "..", "fits", "reference", "fit.json")
    doc = json.load(open(ref, encoding="utf-8"))
    for key, values in change.items():
        doc[key] = dict(doc[key], **values)
    rig = doc["rig"]  # the state's layout holds the rig's n and L
    html = _headline(doc, {"meta": {"n_contact": rig["lugs_in_contact"],
                                    "L_mm": rig["load_bearing_length_mm"]}})
    s = doc["slip"]
    assert ("Reference paper: s = 0.07716" in html) is shown
    assert (fmt.sigma_apart(s["value"], s["std"], REFERENCE_SLIP) + " it" in html) is shown


def test_no_rig_given_no_reference_comparison(tmp_path):
    """A recording fitted without rig.toml runs on the reference robot's values, but nothing
    says the robot is the reference's: no comparison with the paper, and the rig line says
    the values were assumed (issue 44)."""
    from fitlug.io import Rig, find_rig
    from fitlug.report._section_summary import _headline, _rig_line

    (tmp_path / "run.csv").write_text("")
    assert find_rig(tmp_path / "run.csv").assumed and not Rig.reference().assumed
    assert find_rig(tmp_path / "run.csv") == Rig.reference()  # the same values
    from fitlug.fit._problem import build_problem

    from fitlug.io import read_rig, read_trajectories

    bundled = os.path.join(os.path.dirname(__file__), "..", "data", "reference")
    rec = read_trajectories(os.path.join(bundled, "trajectories.csv"))
    assert build_problem(rec, None).rig.assumed
    assert not build_problem(rec, read_rig(os.path.join(bundled, "rig.toml"))).rig.assumed
    ref = os.path.join(os.path.dirname(__file__), "..", "fits", "reference", "fit.json")
    doc = json.load(open(ref, encoding="utf-8"))
    st = {"meta": {"n_contact": 8, "L_mm": 127.0}}
    assert "Reference paper" in _headline(doc, st)
    doc["rig"] = dict(doc["rig"], assumed=True)
    assert "Reference paper" not in _headline(doc, st)
    assert _rig_line(doc, st).startswith("Rig: none given (no rig.toml), the reference "
                                         "robot's values assumed: n = 8")
    doc["rig"] = dict(doc["rig"], assumed=False, drawbar_pull_N=-8.0)
    assert "drawbar pull -8 N (a push)" in _rig_line(doc, st)


def test_log_axes_label_their_ticks_in_plain_text():
    """The report's log axes carry matplotlib's own choice of tick labels, written as
    plain text: each label read back as a number is the tick's value."""
    from fitlug.report._figure import log_axis, new_figure

    sup = str.maketrans("⁰¹²³⁴⁵⁶⁷⁸⁹⁻", "0123456789-")
    for lo, hi in ((1.0, 800.0), (0.15, 3.0), (1e-5, 1e-2)):
        fig, ax = new_figure(4, 3)
        ax = ax[0, 0]
        ax.plot([0, 1], [lo, hi])
        log_axis(ax)
        fig.canvas.draw()
        shown = 0
        for tick in ax.yaxis.get_major_ticks() + ax.yaxis.get_minor_ticks():
            text = tick.label1.get_text()
            if not text or not tick.label1.get_visible():
                continue
            assert "$" not in text and "\\" not in text, text
            mant, _, power = text.replace("−", "-").partition("10")
            value = (float(mant.rstrip("×")) if mant else 1.0) * 10.0 ** float(
                power.translate(sup))
            assert value == pytest.approx(tick.get_loc(), rel=1e-9), (text, tick.get_loc())
            shown += 1
        assert shown >= 2, (lo, hi)


def test_report_draws_without_mathtext(folder, monkeypatch):
    """No figure of the report asks matplotlib's mathtext parser for anything (building
    it cost a third of a second of every run)."""
    import matplotlib.mathtext

    def refuse(self, s, *a, **k):
        raise AssertionError(f"mathtext asked for {s!r}")

    monkeypatch.setattr(matplotlib.mathtext.MathTextParser, "parse", refuse)
    write_report(folder)
    assert (folder / "report.html").stat().st_size > 0


def test_the_estimates_say_a_slip_read_off_the_straight_runs_comes_from_them():
    """Where the model does not describe the path, the headline slip (and Δl′ from it) is
    the straight runs' reading, which the posterior only samples: the table's 'from' says
    so; other quantities keep their source; without that headline, 'posterior'."""
    import re

    from fitlug.report._section_estimates import _estimates

    q = {"value": 0.02, "std": 0.0015, "ci95": [0.017, 0.023]}
    fj = {"slip": q, "delta_l_mm": {**q, "value": 0.3}, "mcmc": {"n_steps": 400},
          "geometry": {"R_mm": 24.4}, "geometry_std": {"R_mm": 0.3},
          "uncertainty_method": "posterior (emcee); the slip read off the straight runs",
          "discrepancy": {"straight_runs": {"method": "belt clock", "slip": 0.02}}}
    st = {"meta": {"least_squares": {}}}

    def sources(html):
        rows = re.findall(r"<tr>(.*?)</tr>", html, re.S)
        cells = [re.findall(r"<t[dh][^>]*>(.*?)</t[dh]>", r, re.S) for r in rows]
        return {c[0]: c[4] for c in cells if len(c) >= 5}

    got = sources(_estimates(fj, st))
    assert got["steady slippage s₀"] == "straight runs (belt clock)"
    assert got["lug deflection Δl′"] == "straight runs (belt clock)"
    assert got["wheel pitch radius R"] == "least squares"
    fj["discrepancy"] = {}  # no straight-runs headline
    assert sources(_estimates(fj, st))["steady slippage s₀"] == "posterior"


def test_the_unexplained_box_names_its_error_once():
    """The unexplained verdict's box ended with the discrepancy's uncertainty method in
    brackets wherever it was not the page's whole method string: a straight-runs headline
    under a posterior ("posterior (emcee); the slip read off ...") repeated the 200-letter
    sentence the page's top already shows. It is named only where the top's does not hold
    it."""
    from fitlug.report._section_summary import _verdict_main

    ref = os.path.join(os.path.dirname(__file__), "..", "fits", "reference", "fit.json")
    doc = json.load(open(ref, encoding="utf-8"))
    how = ("the slip read off the straight runs (the belt's clock against the body, 782 "
           "passages of 4 lug markers)")
    doc["uncertainty_method"] = f"posterior (emcee); {how}; other quantities: robust in time"
    doc["discrepancy"] = dict(doc.get("discrepancy") or {}, verdict="unexplained",
                              slip_after_uncertainty=how, located=[])
    doc["slip"] = dict(doc["slip"], std=10 * doc["slip"]["std"])
    doc["least_squares"] = dict(doc["least_squares"], slip=doc["slip"])
    box = _verdict_main(doc)
    assert "Unexplained" in box and "unmodelled systematic" in box
    assert "passages of 4 lug markers" not in box
    doc["discrepancy"]["slip_after_uncertainty"] = "cluster-robust sandwich by marker"
    assert "(cluster-robust sandwich by marker)" in _verdict_main(doc)


def test_a_frequencys_reading_is_said_once():
    """mu012's unexplained box read the lug-passing frequency twice, ~150 letters each:
    once for the located part (8.3 Hz) and again for the spectral line at 8.27 Hz. The
    line says "(the same)" where its reading is the part's; another reading stays."""
    from fitlug.report._section_discrepancy import located_sentence

    st = {"v_belt_mm_s": 147.7, "pitch_mm": 18.41, "R_mm": 24.5}  # v/p = 8.02 Hz
    part = {"markers": ["C1"], "axis": "y", "segment": "body", "share_of_misfit": 0.33,
            "frequency_hz": 8.3, "t_range_s": [0.13, 4.28]}
    line = {"axis": "y", "segment": "body", "test": "spectral line", "frequency_hz": 8.27}
    s = located_sentence({"straight_runs": st, "located": [part, line]})
    assert s.count("chordal action") == 1 and "8.27 Hz in y (body) (the same)" in s
    other = dict(line, frequency_hz=0.96, axis="x")  # the wheels' turning, 0.959 Hz
    s = located_sentence({"straight_runs": st, "located": [part, other]})
    assert s.count("chordal action") == 1 and "the wheels' turning frequency" in s
    assert "(the same)" not in s


def test_a_reason_for_no_reading_is_given_once_and_no_slip_is_drawn(folder, tmp_path):
    """A run where no slip is read (a spinning track's) gave the same two-line reason for
    all five quantities, five times in the headline box and five in the estimates, and
    'The slip drawn' plotted the compromise fit's s(t) (-300 to +50) as if it were a slip.
    Each box and table gives a shared reason once and names it after; the slip's plots
    give way to a sentence; a quantity with its own reason keeps it."""
    import re
    import shutil

    why = ("the model misses the markers by 14.6 mm rms beyond their noise and the straight "
           "runs give no reading: the marked lugs pass the belt's free part only at 1.7-3.1 s")
    doc = json.load(open(folder / "fit.json", encoding="utf-8"))
    for k in ("slip", "delta_l_mm", "stiffness_N_per_mm", "rolling_resistance",
              "k_over_m_N_per_mm_kg"):
        doc[k] = None
    doc["not_identifiable"] = {"slip": why, "delta_l_mm": why, "stiffness_N_per_mm": why,
                               "rolling_resistance": "its own reason",
                               "k_over_m_N_per_mm_kg": why}
    out = tmp_path / "fit"
    shutil.copytree(folder, out)
    (out / "fit.json").write_text(json.dumps(doc), encoding="utf-8")
    page = open(write_report(out), encoding="utf-8").read()
    body = re.sub(r"<[^>]+>", "", page)
    # once in the headline box, once in the estimates (the mismatch box is not given it)
    assert body.count("14.6 mm rms") == 2
    assert body.count("not identifiable: as the slippage s₀") == 2  # Δl′ and k
    assert body.count("not identifiable: as the steady slippage s₀") == 3  # Δl′, k, k/m
    assert body.count("not identifiable: its own reason") == 2
    assert "No slip is read from this recording" in body
    assert "steady slip s(t) over the recording" not in page  # the figure's alt text
    assert "Stall of" in page or "horizontal stall of one lug marker" in page
    assert "s₀·D = – mm" not in body


def test_a_long_glitch_list_is_folded_after_its_first_rows():
    """An engine recording's misfit flags 100-140 samples of its structure (long_cruise:
    142): the table shows the first GLITCH_ROWS in time order and folds the rest into a
    <details> the reader can open; every row is still in the page, none twice."""
    import re

    from fitlug.report._section_estimates import GLITCH_ROWS, _glitches

    gl = [{"marker": f"B{i % 4:02d}", "time_s": 0.01 * i, "dx_mm": 0.5, "dy_mm": -0.2,
           "size_sigma": 6.0 + i} for i in range(GLITCH_ROWS + 7)]
    html_ = _glitches({"glitches": gl, "glitch_rule": "a rule"})
    shown, folded = html_.split("<details>")
    assert f"({GLITCH_ROWS + 7})" in shown and "the other 7" in folded
    assert len(re.findall(r"<tr>", shown)) == GLITCH_ROWS + 1  # header + rows
    assert len(re.findall(r"<tr>", folded)) == 7 + 1
    assert "</details>" in folded and "Rule: a rule." in folded
    short = _glitches({"glitches": gl[:3], "glitch_rule": "a rule"})
    assert "<details>" not in short and len(re.findall(r"<tr>", short)) == 4


def test_a_law_not_identifiable_is_drawn_as_a_compromise(folder):
    """Where fit.json says k is not identifiable (the model does not describe the path),
    the slip-against-load plot draws the model's law dashed and says why in its label; a
    fitted law stays the solid black line."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    st = load_state(folder)
    fig, (a1, a2) = plt.subplots(1, 2)
    plot_slip_force(st, {"not_identifiable": {"stiffness_N_per_mm": "a compromise"},
                         "slip": {"value": 0.5}}, ax=a1)
    plot_slip_force(st, {}, ax=a2)
    law1 = [ln for ln in a1.get_lines() if "law" in ln.get_label()]
    law2 = [ln for ln in a2.get_lines() if "law" in ln.get_label()]
    assert len(law1) == len(law2) == 1
    assert law1[0].get_linestyle() == "--" and "not identifiable" in law1[0].get_label()
    assert law2[0].get_linestyle() == "-" and law2[0].get_label() == "fitted law s(F)"
    np.testing.assert_array_equal(law1[0].get_ydata(), law2[0].get_ydata())
    # the slip read is drawn, and the axis holds it (not the compromise's range alone)
    read = [ln for ln in a1.get_lines() if ln.get_label() == "the slip read (0.5)"]
    assert len(read) == 1 and a1.get_ylim()[0] < 0.5 < a1.get_ylim()[1]
    plt.close(fig)
