"""The library's public boundary (issue 27): stable names, early and loud errors,
parameters as objects, labelled results."""

from __future__ import annotations

import os
import subprocess
import sys

import pytest

SRC = os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))), "src")


def _run(code: str) -> subprocess.CompletedProcess:
    env = {**os.environ, "PYTHONPATH": SRC + os.pathsep + os.environ.get("PYTHONPATH", "")}
    return subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                          env=env, timeout=120)


# each order touches the three stage names differently before checking both uses
_ORDERS = [
    "import fitlug",
    "import fitlug; fitlug.campaign",
    "import fitlug.fit, fitlug.explain, fitlug.campaign; import fitlug",
    "import fitlug.campaign._law; import fitlug; fitlug.campaign",
]

_CHECK = """
import inspect, fitlug
from fitlug.campaign import fit_points
assert fitlug.campaign.fit_points is fit_points
assert fitlug.campaign.CampaignResult is fitlug.CampaignResult
assert fitlug.fit.FitResult is fitlug.FitResult
assert fitlug.explain.Explanation.__name__ == 'Explanation'
for name in ('fit', 'explain', 'campaign'):
    obj = getattr(fitlug, name)
    assert callable(obj), name
    assert list(inspect.signature(obj).parameters)[0] in ('rec', 'res', 'recordings'), name
try:
    fitlug.fit(None)
except Exception as e:
    print('CALLED', type(e).__name__)
"""


@pytest.mark.parametrize("order", _ORDERS)
def test_stage_names_are_callable_and_sub_packages_in_any_import_order(order):
    """`import fitlug; fitlug.campaign.fit_points` raised AttributeError (the lazy table
    bound the function `campaign` over the sub-package) while `import fitlug.campaign`
    first made it work: now `fitlug.fit`, `.explain`, `.campaign` are always the callable
    sub-packages."""
    out = _run(order + "\n" + _CHECK)
    assert out.returncode == 0, out.stderr[-2000:]
    assert "CALLED" in out.stdout
