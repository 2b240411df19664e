"""The report's words for a slip read off the straight runs (fitlug.explain._straight,
fitlug.explain._belt_clock) and for readings withheld from a misfit the model does not
describe."""

from __future__ import annotations


def straight_sentence(st: dict) -> str:
    """How the headline slip was read where the model does not describe the path: the
    belt's own clock (method 'belt clock') or the top run's visits."""
    if st.get("method") == "belt clock":
        w = st.get("window_s") or [float("nan")] * 2
        c = st.get("cruise_s") or w
        n = st.get("lugs_on_belt")
        same = abs(c[0] - w[0]) < 0.02 and abs(c[1] - w[1]) < 0.02
        return ("the model does not describe the path, so the slip is read off the belt's own "
                "clock: the lug markers' passages of the same places in the body's frame "
                f"({st['passages']} passages of {st['visits']} markers), whole lug pitches "
                + (f"and belt lengths of {n} lugs " if n else "")
                + "apart, give the belt's travel ("
                + (f"{st['v_belt_mm_s']:.2f} mm/s" if same else _window_clause(st, w))
                + f") against the body's ({st['v_body_mm_s']:.2f} mm/s) over the cruise "
                f"from {c[0]:.2f} to {c[1]:.2f} s; " + _error_clause(st, same)
                + _top_run_clause(st))
    return ("the model does not describe the path, so the slip is read off the straight "
            f"runs: the body's mean speed at cruise ({st['v_body_mm_s']:.2f} mm/s) "
            f"against the belt's on the top run ({st['v_belt_mm_s']:.2f} mm/s, "
            f"{st['visits']} visits of a lug marker), as the reference study read its "
            "trajectories; its error carries the speeds' scatter, how much the slip "
            "changes with the window"
            + (f" and {100 * st['straightness_rel']:.1g} % of the belt's speed (the markers' "
               "speed along x is the belt's only where the top run is straight and steady)"
               if st.get("straightness_rel") else ""))


def _error_clause(st: dict, same: bool) -> str:
    """What the clock's error is made of: its largest parts (explain._belt_clock's
    error_terms) in words, and what would narrow it; the parts it carries where the
    reading does not list them (a fit.json of an earlier version)."""
    terms = st.get("error_terms")
    if not terms or not st.get("std") or not st.get("slip"):
        return ("its error carries the passages' scatter"
                + ("" if same else ", the belt speed's trend and that change")
                + " and the body's surge")
    c = st.get("cruise_s") or [0.0, 0.0]
    words = {
        "passages": "the passages' scatter",
        "body noise": "the body markers' noise",
        "pitch": "the lug pitch read off the top run (the rig gives none)",
        "trend": "the belt speed's trend carried from its window to the cruise",
        "unseen belt": "the belt's speed where no passage is seen "
                       f"({100 * st.get('unseen_share', 0.0):.0f} % of the cruise)",
        "surge": {
            "body": f"the body surging on its lugs (its travel swings by "
                    f"{st.get('surge_body_mm', 0.0):.2f} mm about its line over the "
                    f"{c[1] - c[0]:.2f} s of cruise in view)",
            "contact times": f"the slip's swing between the {st.get('batches', 0)} contact "
                             "times in view (the body surging on its lugs)",
            "passages": f"the slip's wander at the passages "
                        f"({st.get('surge_wander_mm', 0.0):.2f} mm: the body surging on "
                        "its lugs)"}.get(st.get("surge_from"), "the body surging on its lugs"),
    }
    var = {k: float(v) ** 2 for k, v in terms.items() if k in words}
    order = sorted(var, key=var.get, reverse=True)
    total = sum(var.values()) or 1.0
    share = var[order[0]] / total
    what = words[order[0]] if share >= 0.5 or len(order) < 2 else \
        f"{words[order[0]]} and {words[order[1]]}"
    hint = ("; a longer cruise in view would narrow it"
            if order[0] in ("surge", "unseen belt") else "")
    return (f"its error (± {st['std']:.4f}, {100 * st['std'] / abs(st['slip']):.0f} % of the "
            f"slip) is {'mostly ' if share >= 0.5 else ''}{what}{hint}")


def _window_clause(st: dict, w) -> str:
    """The belt's speed over a clock window shorter than the cruise, and over the cruise
    (explain._belt_clock.BELT_FOLLOWS: it follows that share of the body's change outside
    the window)."""
    v_w = st.get("v_belt_window_mm_s", st["v_belt_mm_s"])
    f = st.get("belt_follows", 0.5)
    share = "half" if f == 0.5 else f"{f:g} times"
    return (f"{v_w:.2f} mm/s from {w[0]:.2f} to {w[1]:.2f} s where its passages are seen, "
            f"{st['v_belt_mm_s']:.2f} mm/s over the cruise, taken to change by {share} the "
            f"body's change in the other {100 * st.get('unseen_share', 0.0):.0f} % of it")


def _top_run_clause(st: dict) -> str:
    """The top run's disagreeing reading, where the clock's stands against it."""
    top = st.get("top_run_disagrees")
    if not top:
        return ""
    return (f"; the top run's visits read {top['slip']:.4f} ± {top['std']:.4f}, "
            f"{top['apart_in_errors']:.0f} joint errors off and no whole number of lug "
            "pitches: the markers' speed along x, which is the belt's only where the top "
            "run is straight and steady")


def not_claimed_clause(d: dict) -> str:
    """The partial readings withheld from a misfit the model does not describe, or ""."""
    w = d.get("not_claimed") or {}
    if not w.get("readings"):
        return ""
    n = len(w["readings"])
    return ("; " + ", ".join(w["readings"]) + " took up a little of the mismatch and "
            + ("are" if n > 1 else "is") + " not claimed as physics")
