"""Count the programs a `fit-lug` run compiles or reads from JAX's persistent cache, by the
fitlug call site that asked for them (session 42, issue 43).

    python count_compiles.py FILE.csv [fit-lug options...]   # e.g. --rig R --no-mcmc

Runs fitlug.cli.main in this process with jax_log_compiles on; every "Compiling" record
is attributed to the nearest frame of fitlug's source outside fitlug/model/ (the caller
that evaluated the model) and counted. Prints the run's wall seconds, the total and the
40 busiest call sites. An eagerly called JAX function shows as many programs at one site
(jit(add), jit(multiply), ...): one per operation and shape.
"""

import collections
import logging
import re
import sys
import time
import traceback

import jax

where = collections.Counter()
names = collections.Counter()


class _Count(logging.Handler):
    def emit(self, rec):
        m = re.search(r"Compiling (\S+)", rec.getMessage())
        if not m:
            return
        fr = [f for f in traceback.extract_stack()
              if "/fitlug/" in f.filename and "_exported" not in f.filename
              and "/model/" not in f.filename and "_progress" not in f.filename]
        loc = (f"{fr[-1].filename.split('fitlug/')[-1]}:{fr[-1].lineno} {fr[-1].name}"
               if fr else "?")
        where[loc] += 1
        names[m.group(1)] += 1


jax.config.update("jax_log_compiles", True)
_lg = logging.getLogger("jax")
_lg.addHandler(_Count())
_lg.propagate = False

from fitlug.cli import main  # noqa: E402

t = time.time()
try:
    main(sys.argv[1:])
except SystemExit:
    pass
el = time.time() - t
print(f"ARGS {sys.argv[1:]}  {el:.1f} s  {sum(where.values())} programs", file=sys.stderr)
for k, v in where.most_common(40):
    print(f"{v:5d} {k}", file=sys.stderr)
print("by name:", names.most_common(15), file=sys.stderr)
