"""A plugin effect for the test suite (and the example of docs/add-effect.md): the slack
top run holds one full standing wave, path_y += a sin(2 pi xi), xi in [0, 1] along the run.

Installed for a test by putting tests/plugin_pkg on sys.path: the dist-info beside this
package carries the entry point (group ``fitlug.effects``) that fitlug reads."""

import jax.numpy as jnp

from fitlug import Effect


class BeltWave(Effect):
    """The top run flutters in one full wave: path_y += a sin(2 pi xi)."""

    id = "belt_wave"
    defaults = {"wave_a": 0.0}
    scales = {"wave_a": 0.1}
    meaning = ("The slack top run holds a standing wave, so lug markers rise on one half of "
               "the top run and dip on the other.")
    signature = "y:lug:top"

    @classmethod
    def top_dy(cls, p, xi, ctx):
        return p["wave_a"] * jnp.sin(2.0 * jnp.pi * xi)

    @classmethod
    def report(cls, p):
        return {"a_mm": float(p["wave_a"])}
