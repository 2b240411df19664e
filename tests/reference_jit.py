"""jax.jit for the tests' one-shot reference programs (jacfwd of the whole residual
function, to check fitlug's structured Jacobians against).

Such a program is compiled once per test run and called once or twice, so XLA's
optimisation is wasted on it: compiled with the CPU backend's optimisation level 0 and
without the fusion emitters it compiles in about half the time (the whole catalog's
jacfwd: 30 s -> 17 s here) and runs slower by a second. Its values are the same to
rounding (the tests compare at 1e-10 of a column or looser). fitlug's own programs are
never compiled this way.
"""

import jax

FAST_COMPILE = {"xla_backend_optimization_level": 0, "xla_cpu_use_fusion_emitters": False}


def jit_reference(fn):
    """fn compiled for the arguments of each call with FAST_COMPILE (one compile per call
    signature, kept for the process)."""
    jitted = jax.jit(fn)
    compiled = {}

    def call(*args):
        key = tuple((getattr(a, "shape", None), str(getattr(a, "dtype", type(a))))
                    for a in jax.tree_util.tree_leaves(args))
        if key not in compiled:
            compiled[key] = jitted.lower(*args).compile(compiler_options=FAST_COMPILE)
        return compiled[key](*args)

    return call
