"""Where the real data recorded by others lie: the contract's `../shared` beside the checkout
(CI lays its copy there, beside its clone), else this workplace's /work/shared;
FITLUG_SHARED overrides both. Tests that need it skip, saying why, when it is absent."""

import os

_ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def _shared() -> str:
    for path in (os.environ.get("FITLUG_SHARED"), os.path.join(os.path.dirname(_ROOT), "shared"),
                 "/work/shared"):
        if path and os.path.isdir(os.path.join(path, "data", "real")):
            return path
    return os.path.join(os.path.dirname(_ROOT), "shared")


SHARED = _shared()
REAL = os.path.join(SHARED, "data", "real")
