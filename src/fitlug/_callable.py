"""Sub-packages named after their main function (``fitlug.fit``, ``fitlug.explain``,
``fitlug.campaign``) stay callable as that function.

``fitlug.fit(rec, rig)`` is the README's call, resolved lazily by ``fitlug.__getattr__``.
But once anything imports the sub-package ``fitlug.fit`` (``fitlug.explain`` does), the
import system sets the attribute ``fitlug.fit`` to that module, and the call failed with
"'module' object is not callable". The module's class is made callable instead, calling
the function of the same name, and ``fitlug.__getattr__`` always answers the sub-package
(never the bare function), so that ``fitlug.campaign.fit_points`` and
``fitlug.campaign(...)`` both work in any import order."""

from __future__ import annotations

import sys
import types


class _CallableModule(types.ModuleType):
    def __call__(self, *args, **kwargs):
        return getattr(self, self.__name__.rsplit(".", 1)[-1])(*args, **kwargs)

    @property
    def __signature__(self):
        """The signature of the function the module calls (``inspect.signature``)."""
        import inspect

        return inspect.signature(getattr(self, self.__name__.rsplit(".", 1)[-1]))


def make_callable(module_name: str) -> None:
    """Make the module `module_name` call its function of the same (last) name."""
    sys.modules[module_name].__class__ = _CallableModule
