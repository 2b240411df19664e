"""The house's layout (issue 31): no import cycle, imports follow the stages, short modules.

The truth here is the rule the founders wrote, not anything the code produced: the stages
run io -> model -> fit -> explain -> posterior -> report, vision feeding io (the tracker
writes its trajectories with io's writer, so vision may import io and io never vision), the
simulator and campaigns on top and the CLI over everything; a module imports only from its own stage or
an earlier one; no two modules import each other, directly or round a loop (lazy imports
inside functions count too: they are the same dependency, paid later); a module past about
400 lines says at its top why.
"""

from __future__ import annotations

import ast
import pathlib
import sys

import pytest

SRC = pathlib.Path(__file__).resolve().parents[1] / "src" / "fitlug"

# lower rank = earlier stage; a module may import from its own rank or lower.
STAGES = ["(top)", "io", "vision", "model", "fit", "explain", "posterior", "report",
          "plot", "sim", "campaign", "cli"]
MAX_LINES = 420
# upward imports made on purpose, each with its reason: a result's `summary()` is the
# terminal's text, which the report stage formats (from fit.json's fields); the method
# imports it on call, so the fit and explain stages load nothing of report's until asked
ALLOWED_UPWARD = {
    ("fitlug.fit._result", "fitlug.report"),
    ("fitlug.explain._display", "fitlug.report"),
}
LONG_REASON = "Longer than 400 lines because"


def _modules() -> dict[str, pathlib.Path]:
    mods = {}
    for path in SRC.rglob("*.py"):
        parts = list(path.relative_to(SRC.parent).with_suffix("").parts)
        if parts[-1] == "__init__":
            parts = parts[:-1]
        mods[".".join(parts)] = path
    return mods


def _imports(mods: dict[str, pathlib.Path]) -> dict[str, set[str]]:
    edges: dict[str, set[str]] = {}
    for name, path in mods.items():
        is_pkg = path.name == "__init__.py"
        out: set[str] = set()
        for node in ast.walk(ast.parse(path.read_text(), str(path))):
            targets = []
            if isinstance(node, ast.Import):
                targets = [a.name for a in node.names]
            elif isinstance(node, ast.ImportFrom):
                if node.level:
                    base = name.split(".")
                    if not is_pkg:
                        base = base[:-1]
                    base = base[: len(base) - (node.level - 1)]
                    mod = ".".join(base + ([node.module] if node.module else []))
                else:
                    mod = node.module or ""
                targets = [mod] + [f"{mod}.{a.name}" for a in node.names]
            if (isinstance(node, ast.Call) and getattr(node.func, "attr", None) == "import_module"
                    and node.args and isinstance(node.args[0], ast.Constant)
                    and isinstance(node.args[0].value, str)):
                targets = [node.args[0].value]  # importlib.import_module("fitlug.x") too
            for t in targets:
                if not t.startswith("fitlug"):
                    continue
                while t not in mods and "." in t:
                    t = t.rsplit(".", 1)[0]
                if t in mods and t != name:
                    out.add(t)
        edges[name] = out
    return edges


def _stage(module: str) -> str:
    parts = module.split(".")
    if len(parts) >= 2 and (SRC / parts[1]).is_dir():
        return parts[1]
    return "(top)"


def _cycles(nodes, edges):
    """Strongly connected components of more than one module (Tarjan)."""
    sys.setrecursionlimit(max(10000, sys.getrecursionlimit()))
    index, low, stack, on, found, counter = {}, {}, [], set(), [], [0]

    def visit(v):
        index[v] = low[v] = counter[0]
        counter[0] += 1
        stack.append(v)
        on.add(v)
        for w in edges.get(v, ()):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on.discard(w)
                comp.append(w)
                if w == v:
                    break
            if len(comp) > 1:
                found.append(sorted(comp))

    for v in sorted(nodes):
        if v not in index:
            visit(v)
    return found


def test_no_import_cycle_between_modules():
    mods = _modules()
    edges = _imports(mods)
    # a package's __init__ re-exports its own modules: that is a facade, not a cycle
    plain = {m for m, p in mods.items() if p.name != "__init__.py"}
    sub = {a: {b for b in bs if b in plain} for a, bs in edges.items() if a in plain}
    assert _cycles(plain, sub) == []


def test_imports_follow_the_stages():
    mods = _modules()
    edges = _imports(mods)
    upward = []
    for a, bs in edges.items():
        sa = _stage(a)
        assert sa in STAGES, f"{a}: stage {sa!r} is not in the house's order {STAGES}"
        for b in bs:
            sb = _stage(b)
            if (sb != "(top)" and STAGES.index(sb) > STAGES.index(sa) and sa != "(top)"
                    and (a, b) not in ALLOWED_UPWARD):
                upward.append(f"{a} -> {b}")
    assert upward == []


def test_modules_are_short_or_say_why():
    long = []
    for name, path in _modules().items():
        text = path.read_text()
        n = text.count("\n")
        if n > MAX_LINES:
            doc = ast.get_docstring(ast.parse(text)) or ""
            if LONG_REASON not in doc:
                long.append(f"{path.relative_to(SRC.parent)}: {n} lines")
    assert long == []


def test_vision_is_made_of_sub_packages():
    loose = sorted(p.name for p in (SRC / "vision").glob("*.py") if p.name != "__init__.py")
    subs = sorted(p.name for p in (SRC / "vision").iterdir()
                  if p.is_dir() and (p / "__init__.py").exists())
    assert loose == []
    assert {"read", "calibrate", "detect", "track"} <= set(subs)


@pytest.mark.parametrize("module", ["fitlug.vision", "fitlug.sim"])
def test_the_camera_simulator_lives_in_sim(module):
    names = {p.stem for p in (SRC / module.split(".")[1]).rglob("*.py")}
    if module == "fitlug.vision":
        assert not names & {"_render", "_render_video", "_scene", "_overlay"}
    else:
        assert {"_render", "_render_video", "_scene"} <= names
