"""Dependencies between imucald's packages point one way.

Allowed direction (an arrow: "may import"):

    cli         -> plots, mqtt, gap, daemon, orientation, sim, drivers, fitting, files, numerics
                   (the top: it builds the board, real or emulated, and wires everything)
    plots       -> fitting                           (pictures: matplotlib, the plots extra)
    mqtt        -> daemon
                   (the bridge: a client of the daemon's sockets and config)
    gap         -> fitting, files, numerics
                   (the diagnosis refits with fitting's kernels; never sim)
    daemon      -> orientation, drivers, fitting, files, numerics
                   (the production path: never sim or gap)
    orientation -> (none of these)                   (the filter shell and quaternion math)
    sim         -> drivers, fitting, files, numerics
                   (the emulated chips share the drivers' register maps)
    drivers     -> (none of these)
                   (the bus layer, the register maps, one driver per chip)
    fitting     -> files, numerics                   (pure functions over numpy arrays)
    files       -> numerics                          (what imucald reads and writes)
    numerics    -> (none of these)                   (helpers over numpy arrays and numbers)

Top-level leaves that import no package above: imucald.specs, imucald.errors,
imucald.stillness_defaults.  Every ``import`` and ``from ... import`` counts, at module level
and inside functions, since a lazy import is still a dependency.
"""
import ast
import os

import pytest

ROOT = os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))), "imucald")
PACKAGES = ("cli", "plots", "mqtt", "gap", "daemon", "orientation", "sim", "drivers",
            "fitting", "files", "numerics")
ALLOWED = {
    "cli": {"plots", "mqtt", "gap", "daemon", "orientation",
            "sim", "drivers", "fitting", "files", "numerics"},
    "plots": {"fitting"},
    "mqtt": {"daemon"},
    "gap": {"fitting", "files", "numerics"},
    "daemon": {"orientation", "drivers", "fitting", "files", "numerics"},
    "orientation": set(),
    "sim": {"drivers", "fitting", "files", "numerics"},
    "drivers": set(),
    "fitting": {"files", "numerics"},
    "files": {"numerics"},
    "numerics": set(),
}


def _module_name(path, root=ROOT):
    rel = os.path.relpath(path, os.path.dirname(root))[:-3].split(os.sep)
    return rel[:-1] if rel[-1] == "__init__" else rel, rel[-1] == "__init__"


def _imports(path, root=ROOT):
    """Absolute module names imported by one file (relative imports resolved)."""
    parts, is_pkg = _module_name(path, root)
    pkg = parts if is_pkg else parts[:-1]
    tree = ast.parse(open(path, encoding="utf-8").read(), path)
    for node in ast.walk(tree):              # module level and inside functions alike
        if isinstance(node, ast.Import):
            for a in node.names:
                yield node.lineno, a.name
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = pkg[:len(pkg) - (node.level - 1)]
                mod = ".".join(base + ([node.module] if node.module else []))
            else:
                mod = node.module or ""
            yield node.lineno, mod
            for a in node.names:             # "from . import sim" imports a package too
                yield node.lineno, f"{mod}.{a.name}"


TOP = {f[:-3] for f in os.listdir(ROOT) if f.endswith(".py") and f != "__init__.py"}


def _package_of(module):
    """The node a module belongs to: one of PACKAGES, a top-level module (calibration,
    api, specs ...), "imucald" for the package itself, or None outside imucald."""
    p = module.split(".")
    if p[0] != "imucald":
        return None
    if len(p) == 1 or p[1] == "__init__":
        return "imucald"
    return p[1] if p[1] in PACKAGES or p[1] in TOP else None


def package_edges(root=ROOT):
    """{(from_package, to_package): [file:line, ...]} over imucald/**.py."""
    edges = {}
    for d, _, files in os.walk(root):
        for f in files:
            if not f.endswith(".py"):
                continue
            path = os.path.join(d, f)
            src = _package_of(".".join(_module_name(path, root)[0]))
            for line, mod in _imports(path, root):
                dst = _package_of(mod)
                if dst and dst != src:
                    edges.setdefault((src, dst), []).append(f"{os.path.relpath(path, root)}:{line}")
    return edges


def _cycles(edges):
    graph = {}
    for a, b in edges:
        graph.setdefault(a, set()).add(b)
    found = []

    def walk(node, path):
        for nxt in sorted(graph.get(node, ())):
            if nxt == path[0]:
                found.append(path + [nxt])
            elif nxt not in path and nxt > path[0]:     # each cycle once, from its least node
                walk(nxt, path + [nxt])
    for start in sorted(graph):
        walk(start, [start])
    return found


def test_no_import_cycle_between_packages():
    edges = package_edges()
    cycles = _cycles(edges)
    assert not cycles, "; ".join(
        " -> ".join(c) + " (" + ", ".join(edges[(c[i], c[i + 1])][0] for i in range(len(c) - 1)) + ")"
        for c in cycles)


def test_every_package_import_is_in_the_allowed_direction():
    bad = {k: v for k, v in package_edges().items()
           if k[0] in PACKAGES and k[1] in PACKAGES and k[1] not in ALLOWED[k[0]]}
    assert not bad, "; ".join(f"{a} -> {b} at {', '.join(w)}" for (a, b), w in sorted(bad.items()))


def test_every_allowed_edge_is_one_that_exists():
    """The table is exactly the edges the imports make: an allowance nothing uses is a door
    left open.  (Checked broken: with gap -> sim allowed again, which no import uses, this
    fails naming it.)"""
    have = {k for k in package_edges() if k[0] in PACKAGES and k[1] in PACKAGES}
    unused = sorted((a, b) for a, bs in ALLOWED.items() for b in bs if (a, b) not in have)
    assert not unused, "allowed but unused: " + ", ".join(f"{a} -> {b}" for a, b in unused)


def test_leaves_import_no_package():
    for leaf in ("specs.py", "errors.py", "stillness_defaults.py"):
        mods = [m for _, m in _imports(os.path.join(ROOT, leaf)) if _package_of(m) in PACKAGES]
        assert not mods, f"{leaf} imports {mods}"


def test_the_walker_sees_function_level_and_relative_imports(tmp_path):
    """The check itself can fail: a lazy relative import that closes a cycle is found."""
    pkg = tmp_path / "imucald"
    for p in ("fitting", "sim"):
        (pkg / p).mkdir(parents=True)
        (pkg / p / "__init__.py").write_text("")
    (pkg / "fitting" / "fit.py").write_text("def f():\n    from ..sim.sensor import Truth\n")
    (pkg / "sim" / "sensor.py").write_text("from ..fitting import fit\n")
    edges = package_edges(str(pkg))
    assert set(edges) == {("fitting", "sim"), ("sim", "fitting")}
    assert _cycles(edges) == [["fitting", "sim", "fitting"]]


if __name__ == "__main__":
    pytest.main([__file__])


def test_no_function_in_imucald_is_over_80_lines():
    """Issue 24: a function that does one step of a pipeline fits on a screen.  Seen to fail
    on the merged tree before gap/search.py's stepwise (159 lines) was split into its moves."""
    import ast
    import pathlib
    root = pathlib.Path(__file__).resolve().parent.parent / "imucald"
    long = []
    for p in sorted(root.rglob("*.py")):
        for n in ast.walk(ast.parse(p.read_text(encoding="utf-8"))):
            if isinstance(n, (ast.FunctionDef, ast.AsyncFunctionDef)):
                lines = n.end_lineno - n.lineno + 1
                if lines > 80:
                    long.append(f"{p.relative_to(root.parent)}:{n.lineno} {n.name} ({lines} lines)")
    assert not long, "functions over 80 lines: " + "; ".join(long)


def test_no_module_imports_another_modules_private_names():
    """Issue 24: what one module takes from another is public where it lives (no `_name`
    imported across modules).  Seen to fail before the helpers were renamed (calibration.py
    took seven `_check` helpers from files/calibration_checks, cli/calall took offline's)."""
    import ast
    import pathlib
    root = pathlib.Path(__file__).resolve().parent.parent / "imucald"
    found = []
    for p in sorted(root.rglob("*.py")):
        for n in ast.walk(ast.parse(p.read_text(encoding="utf-8"))):
            if isinstance(n, ast.ImportFrom) and (n.level > 0 or (n.module or "").startswith("imucald")):
                priv = [a.name for a in n.names if a.name.startswith("_") and not a.name.startswith("__")]
                if priv:
                    found.append(f"{p.relative_to(root.parent)}:{n.lineno} {n.module} {priv}")
    assert not found, "private names imported across modules: " + "; ".join(found)
