"""An Explanation for people: a one-line repr, a compact HTML table, the terminal's text."""

from __future__ import annotations

import html as _html


def check_result(res) -> None:
    """Raise TypeError unless `res` is a FitResult (explain's argument)."""
    from ..fit import FitResult

    if not isinstance(res, FitResult):
        raise TypeError(f"explain needs the FitResult of fitlug.fit(...), got "
                        f"{type(res).__name__}")


def short_repr(ex) -> str:
    return (f"<Explanation: {ex.verdict}; effects: {', '.join(ex.effects) or 'none'}; "
            f"final {ex.final!r}>")


def html(ex) -> str:
    return (f"<div><b>{_html.escape(ex.verdict)}</b>: "
            f"{_html.escape(', '.join(ex.effects) or 'no effect added')}"
            f"{ex.final._repr_html_()}</div>")


def summary(ex) -> str:
    """fitlug.summary of the explanation (the report stage formats it; imported on call)."""
    import importlib

    return importlib.import_module("fitlug.report").summary(ex)
