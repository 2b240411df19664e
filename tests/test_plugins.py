"""Effects as plugins (issue 27, item 6): the public base class, register_effect, entry
points of the group fitlug.effects, and the disk cache of compiled programs keyed on a
plugin's code, so that an edited effect under the same id is never served stale.

The truth: the simulator draws a recording with the plugin effect at a known amplitude
(the fit must recover it), and an edit that doubles the effect must double the model's
response in a new process (a stale program would return the old one)."""

from __future__ import annotations

import json
import os
import pathlib
import subprocess
import sys
import textwrap

import numpy as np
import pytest

import fitlug
from fitlug.model import Effect, register_effect, unregister_effect
from fitlug.model.effects import CATALOG, plugins

PLUGIN_PKG = pathlib.Path(__file__).parent / "plugin_pkg"
SRC = pathlib.Path(fitlug.__file__).resolve().parents[1]


def _run(code: str, *paths, env=None) -> str:
    e = dict(os.environ, PYTHONPATH=os.pathsep.join([str(SRC), *map(str, paths)]), **(env or {}))
    out = subprocess.run([sys.executable, "-c", textwrap.dedent(code)], capture_output=True,
                         text=True, env=e, timeout=300)
    assert out.returncode == 0, out.stderr[-3000:]
    return out.stdout


def test_public_names():
    assert fitlug.Effect is Effect and fitlug.register_effect is register_effect
    assert "belt_sag" in CATALOG and not plugins()


def test_entry_point_plugin_is_loaded_at_the_catalogs_first_use():
    out = _run("""
        import sys, fitlug
        from fitlug.model.effects import CATALOG
        before = "fitlug_belt_wave" in sys.modules
        ids = list(CATALOG)
        print(before, ids[-1], CATALOG["belt_wave"].__module__, len(ids))
    """, PLUGIN_PKG)
    assert out.split() == ["False", "belt_wave", "fitlug_belt_wave", "14"]  # 13 own + 1


def _wave(**over):
    attrs = dict(id="wave_t", defaults={"wavet_a": 0.0}, scales={"wavet_a": 0.1},
                 top_dy=classmethod(lambda cls, p, xi, ctx: p["wavet_a"] * xi))
    attrs.update(over)
    return type("WaveT", (Effect,), attrs)


@pytest.mark.parametrize("over, error, words", [
    ({"id": "Wave T"}, ValueError, "lower-case identifier"),
    ({"id": "belt_sag"}, ValueError, "fitlug's own"),
    ({"defaults": {"sag_d": 0.0}, "scales": {"sag_d": 0.1}}, ValueError, "effect 'belt_sag'"),
    ({"defaults": {"R": 0.0}, "scales": {"R": 0.1}}, ValueError, "base model"),
    ({"scales": {"other": 1.0}}, TypeError, "different parameters"),
    ({"top_dy": None}, TypeError, "no hook"),
    ({"fixed_in_fit": ("nope",)}, TypeError, "fixed_in_fit"),
])
def test_register_effect_names_the_mistake(over, error, words):
    with pytest.raises(error, match=words):
        register_effect(_wave(**over))
    assert "wave_t" not in CATALOG
    with pytest.raises(TypeError, match="not a subclass"):
        register_effect(dict)


def test_register_replace_and_unregister():
    a, b = _wave(), _wave()
    try:
        assert register_effect(a) is a and plugins() == ["wave_t"]
        register_effect(a)  # the same class again: nothing to do
        with pytest.raises(ValueError, match="replace=True"):
            register_effect(b)
        register_effect(b, replace=True)
        assert CATALOG["wave_t"] is b
    finally:
        unregister_effect("wave_t")
    assert "wave_t" not in CATALOG
    with pytest.raises(ValueError, match="fitlug's own"):
        unregister_effect("belt_sag")


def test_registered_effect_is_fitted_and_recovered_on_a_simulated_recording():
    sys.path.insert(0, str(PLUGIN_PKG))
    try:
        from fitlug_belt_wave import BeltWave
    finally:
        sys.path.remove(str(PLUGIN_PKG))
    from fitlug.sim import Scenario, rig_of, simulate

    register_effect(BeltWave)
    try:
        sc = Scenario(duration_s=1.5, travel_mm=150, rest_s=0.2, ramp_s=0.4,
                      effects={"belt_wave": {"wave_a": 0.3}})
        rec, _ = simulate(sc, 5)
        res = fitlug.fit(rec, rig_of(sc), effects=["belt_wave"])
        i = res.packing.slices()["wave_a"].start
        a, sa = float(res.params["wave_a"]), float(np.sqrt(res.cov[i, i]))
        assert res.effects == ("belt_wave",)
        assert abs(a - 0.3) < 5 * sa and sa < 0.03
        assert res.effect_params("belt_wave") == {"a_mm": pytest.approx(float(a))}
        assert 0.8 < res.chi2_per_dof < 1.25
    finally:
        unregister_effect("belt_wave")


_EFFECT = """
import jax.numpy as jnp
from fitlug.model import Effect, register_effect

@register_effect
class EditedWave(Effect):
    id = "edited_wave"
    defaults = {{"edw_a": 0.0}}
    scales = {{"edw_a": 0.1}}

    @classmethod
    def body_dy(cls, p, psi, cx, ctx):
        return {factor} * p["edw_a"] * jnp.sin(psi / ctx.R)
"""

_PREDICT = """
import json, sys
import jax, jax.numpy as jnp, numpy as np
import user_effect  # registers edited_wave
from fitlug import _exported
from fitlug.model import predict
from fitlug.sim import Scenario, truth_params
from fitlug.sim._simulate import _truth_layout

sc = Scenario(duration_s=1.2, rest_s=0.1, ramp_s=0.4, travel_mm=100, lug_markers=3)
t = np.arange(0, 1.2, 0.05)
lay, br = _truth_layout(sc, np.repeat(t, 3), np.tile(np.arange(3), len(t)),
                        np.repeat(t, 2), np.tile(np.arange(2), len(t)))
lay = lay.with_effects(("edited_wave",))
p = truth_params(sc, lay, br)
f = jax.jit(lambda p, lay: tuple(predict(p, lay)))
ly = {}
for a in (0.0, 0.3):
    p["edw_a"] = jnp.asarray(a)
    ly[a] = np.asarray(_exported.call("plugin_predict", f, (), p, lay)[3])
print(json.dumps(list(ly[0.3] - ly[0.0])))
"""


def test_an_edited_effect_is_never_served_a_stale_compiled_program(tmp_path):
    """The issue: after editing an effect under the same id, the next process reused the
    old program from the disk cache (chi2/dof 1.011 instead of 4.189)."""
    mod, script = tmp_path / "user_effect.py", tmp_path / "predict.py"
    script.write_text(_PREDICT)
    env = {"FITLUG_CACHE_DIR": str(tmp_path / "cache")}
    diffs = []
    for factor in ("1.0", "2.0"):
        mod.write_text(_EFFECT.format(factor=factor))
        out = _run(f"import runpy; runpy.run_path({str(script)!r})", tmp_path, env=env)
        diffs.append(np.array(json.loads(out)))
    kept = list((tmp_path / "cache" / "exported").glob("plugin_predict-*.jaxexport"))
    assert len(kept) == 2  # one program per version of the effect's code, both on disk
    assert np.max(np.abs(diffs[0])) > 0.1  # the effect moves the body markers
    np.testing.assert_allclose(diffs[1], 2 * diffs[0], rtol=1e-9, atol=1e-9)
