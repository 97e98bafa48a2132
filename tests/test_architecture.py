"""The layering and size rules of docs/architecture.md, checked on the source tree.

Each rule reads the code with :mod:`ast` (nothing is imported), so a violation names the file
and line that breaks it.
"""

from __future__ import annotations

import ast
import functools
import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("tracker", "pipeline", "sources", "sinks")
NAMESPACE = "bnptrack."  # the installed name of each package: bnptrack.tracker, ... (pyproject.toml)
MAX_MODULE_LINES = 500  # every package
MAX_CLASS_LINES = 300  # every package
MAX_FUNCTION_LINES = 60  # everywhere except numba kernels
MAX_KERNEL_ARGS = 10  # positional arguments of a numba kernel in tracker/: more are bundled (NamedTuples)

#: Modules still over MAX_MODULE_LINES, each with its current length as its ceiling: an entry
#: goes when its module is split (a module below the limit must leave the list).
LONG_MODULES: dict[str, int] = {}

#: Classes still over MAX_CLASS_LINES, each with its current length as its ceiling.
LONG_CLASSES: dict[str, int] = {}

#: numba kernels still over MAX_KERNEL_ARGS positional arguments, each with its exact count
#: (an entry changes or goes when its arguments are bundled).
WIDE_KERNELS: dict[str, int] = {
    "tracker/bnp/gibbs_sweeps.py:_sweep_kernel": 26, "tracker/bnp/gibbs_sweeps.py:_site_pass": 23,
    "tracker/bnp/gibbs.py:_chains_kernel": 23,
    "tracker/bnp/swap_moves.py:swap_scan": 14, "tracker/bnp/swap_moves.py:swap_pass": 14,
    "tracker/models/_kernels.py:_moments": 14, "tracker/bnp/gibbs_setup.py:_setup_kernel": 13,
    "tracker/bnp/swap_moves.py:_exchange": 11, "tracker/bnp/group_theta.py:_transition_kernel": 11,
    "tracker/models/_kernels.py:loglik_balls": 12,
}


def _modules() -> dict[str, Path]:
    out = {}
    for pkg in PACKAGES:
        for path in sorted((ROOT / pkg).rglob("*.py")):
            rel = path.relative_to(ROOT).with_suffix("")
            parts = rel.parts[:-1] if rel.name == "__init__" else rel.parts
            out[".".join(parts)] = path
    return out


MODULES = _modules()


@pytest.fixture(scope="module", autouse=True)
def _release_the_trees():
    """The parsed trees are shared by this module's rules and dropped after them (hundreds of
    thousands of nodes would otherwise slow every later garbage collection of the run)."""
    yield
    for cached in (_parse, _walk, _imports):
        cached.cache_clear()


@functools.lru_cache(maxsize=None)
def _parse(text: str, filename: str) -> ast.Module:
    """One parse per file text: the rules below walk the same modules many times."""
    return ast.parse(text, filename=filename)


@functools.lru_cache(maxsize=None)
def _walk(text: str, filename: str) -> tuple[ast.AST, ...]:
    """Every node of one file text, in :func:`ast.walk`'s order: one walk per text, shared by
    the rules below."""
    return tuple(ast.walk(_parse(text, filename)))


def _nodes(path: Path) -> tuple[ast.AST, ...]:
    return _walk(path.read_text(), str(path))


_STRING_IMPORTERS = ("warm_imports", "import_module", "__import__")


def _string_imports(node: ast.AST) -> list[str]:
    """Modules named in strings: ``warm_imports("a.b")`` / ``importlib.import_module("a.b")``
    arguments and ``"package.module:attribute"`` factory strings (e.g. the table of sinks)."""
    if isinstance(node, ast.Call) and ast.unparse(node.func).split(".")[-1] in _STRING_IMPORTERS:
        return [a.value for a in node.args if isinstance(a, ast.Constant) and isinstance(a.value, str)]
    if isinstance(node, ast.Constant) and isinstance(node.value, str):
        m = re.fullmatch(r"([a-z_][\w.]*):[A-Za-z_]\w*", node.value)
        if m and _local(m.group(1)).split(".")[0] in PACKAGES:
            return [m.group(1)]
    return []


def _local(name: str) -> str:
    """``bnptrack.tracker.x`` -> ``tracker.x``: the rules speak of the repository's folders."""
    return name[len(NAMESPACE):] if name.startswith(NAMESPACE) else name


@functools.lru_cache(maxsize=None)
def _imports(path: Path) -> tuple[tuple[str, int], ...]:
    """Every absolute module name imported anywhere in ``path`` (also inside functions, and
    named in strings that are imported later: see :func:`_string_imports`). Read once per run:
    the rules that use it read only the project's modules, which do not change while it runs."""
    mod = ".".join(path.relative_to(ROOT).with_suffix("").parts)
    found = []
    for node in _nodes(path):
        if isinstance(node, ast.Import):
            found += [(a.name, node.lineno) for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            if node.level:  # relative: resolve against this module's package
                base = mod.split(".")[: -node.level]
                name = ".".join(base + ([node.module] if node.module else []))
            else:
                name = node.module or ""
            found.append((name, node.lineno))
            found += [(f"{name}.{a.name}", node.lineno) for a in node.names]
        found += [(name, getattr(node, "lineno", 0)) for name in _string_imports(node)]
    return tuple((_local(name), line) for name, line in found)


def _top(name: str) -> str:
    return name.split(".")[0]


def _violations(rule) -> list[str]:
    bad = []
    for mod, path in MODULES.items():
        for name, line in _imports(path):
            if rule(mod, name):
                bad.append(f"{path.relative_to(ROOT)}:{line} imports {name}")
    return sorted(set(bad))


def test_sources_and_sinks_do_not_import_the_pipeline():
    assert _violations(lambda m, n: _top(m) in ("sources", "sinks") and _top(n) == "pipeline") == []


def test_sinks_do_not_import_sources():
    assert _violations(lambda m, n: _top(m) == "sinks" and _top(n) == "sources") == []


def test_sources_do_not_import_sinks():
    assert _violations(lambda m, n: _top(m) == "sources" and _top(n) == "sinks") == []


def test_tracker_imports_nothing_above_it():
    assert _violations(lambda m, n: _top(m) == "tracker" and _top(n) in ("pipeline", "sources", "sinks")) == []


def test_the_tracker_floor_does_no_io():
    """No transport, log format or viewer below the pipeline's and the sinks' adapters."""
    io = ("zenoh", "mcap", "rerun")
    assert _violations(lambda m, n: _top(m) == "tracker" and _top(n) in io) == []


def test_string_imports_count_as_edges():
    tree = ast.parse('SINKS = {"a": Entry("sinks.mcap_sink:McapSink")}\nwarm_imports("pipeline.resolve", "x")')
    names = [n for node in ast.walk(tree) for n in _string_imports(node)]
    assert sorted(names) == ["pipeline.resolve", "sinks.mcap_sink", "x"]


def test_only_the_transport_imports_zenoh():
    transport = {"pipeline.transport", "pipeline.transport_session", "pipeline.transport_liveliness"}
    assert _violations(lambda m, n: _top(n) == "zenoh" and m not in transport) == []


def _may_import_rerun(mod: str) -> bool:
    return mod.startswith("sinks.rerun_") or mod == "pipeline.view"


def test_only_rerun_modules_and_the_viewer_import_rerun():
    assert _violations(lambda m, n: _top(n) == "rerun" and not _may_import_rerun(m)) == []


def _graph() -> dict[str, set[str]]:
    graph: dict[str, set[str]] = {m: set() for m in MODULES}
    for mod, path in MODULES.items():
        for name, _ in _imports(path):
            # "from pkg import mod" names a module; "from mod import func" names its module
            target = name if name in MODULES else name.rpartition(".")[0]
            if target in MODULES and target != mod and not mod.startswith(target + "."):
                graph[mod].add(target)
    return graph


def _cycle(graph: dict[str, set[str]]) -> list[str] | None:
    state: dict[str, int] = {}
    stack: list[str] = []

    def visit(node: str) -> list[str] | None:
        state[node] = 1
        stack.append(node)
        for nxt in sorted(graph[node]):
            if state.get(nxt) == 1:
                return stack[stack.index(nxt):] + [nxt]
            if nxt not in state and (found := visit(nxt)):
                return found
        stack.pop()
        state[node] = 2
        return None

    for node in sorted(graph):
        if node not in state and (found := visit(node)):
            return found
    return None


def test_no_import_cycles():
    assert _cycle(_graph()) is None


def test_the_cycle_finder_finds_a_cycle():
    assert _cycle({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": set()}) == ["a", "b", "c", "a"]
    assert _cycle({"a": {"b"}, "b": set()}) is None


def _over(found: dict[str, int], limit: int, allowed: dict[str, int]) -> list[str]:
    """What breaks a size rule: an entry of ``found`` over ``limit`` and not allowed, or over its
    ceiling in ``allowed``; and an allowed entry that is gone or back under ``limit``."""
    bad = [f"{k} ({n} lines)" for k, n in found.items() if n > limit and n > allowed.get(k, limit)]
    bad += [f"{k}: in the allow-list but {found.get(k, 0)} lines" for k in allowed if found.get(k, 0) <= limit]
    return sorted(bad)


def _module_lengths(pkg: str) -> dict[str, int]:
    return {str(p.relative_to(ROOT)): len(p.read_text().splitlines()) for p in sorted((ROOT / pkg).rglob("*.py"))}


def _class_lengths(path: Path) -> dict[str, int]:
    return {f"{_rel(path)}:{n.name}": n.end_lineno - n.lineno + 1 for n in _nodes(path) if isinstance(n, ast.ClassDef)}


@pytest.mark.parametrize("pkg", PACKAGES)
def test_modules_stay_small(pkg):
    allowed = {k: v for k, v in LONG_MODULES.items() if k.startswith(pkg + "/")}
    assert _over(_module_lengths(pkg), MAX_MODULE_LINES, allowed) == []


@pytest.mark.parametrize("pkg", PACKAGES)
def test_classes_stay_small(pkg):
    found = {k: n for p in sorted((ROOT / pkg).rglob("*.py")) for k, n in _class_lengths(p).items()}
    allowed = {k: v for k, v in LONG_CLASSES.items() if k.startswith(pkg + "/")}
    assert _over(found, MAX_CLASS_LINES, allowed) == []


def test_the_size_rules_see_a_long_class_and_a_stale_entry(tmp_path):
    body = "\n".join(f"    x{i} = {i}" for i in range(300))
    path = tmp_path / "probe.py"
    path.write_text(f"class A:\n{body}\n\nclass B:\n    y = 1\n")
    found = _class_lengths(path)
    assert found == {"probe.py:A": 301, "probe.py:B": 2}
    assert _over(found, 300, {}) == ["probe.py:A (301 lines)"]
    assert _over(found, 300, {"probe.py:A": 301}) == []
    assert _over(found, 300, {"probe.py:A": 300, "probe.py:B": 9}) == [
        "probe.py:A (301 lines)", "probe.py:B: in the allow-list but 2 lines"]


def _private_imports(path: Path, root: Path = ROOT) -> list[str]:
    """Private names (``_x``, or a module ``_x`` on the path) imported from another package."""
    rel = path.relative_to(root)
    mine = rel.parts[0]
    out = []
    for node in _nodes(path):
        if isinstance(node, ast.ImportFrom) and not node.level:
            names = [f"{node.module}.{a.name}" for a in node.names]
        elif isinstance(node, ast.Import):
            names = [a.name for a in node.names]
        else:
            continue
        for name in names:
            parts = _local(name).split(".")
            if parts[0] in PACKAGES and parts[0] != mine and any(s.startswith("_") for s in parts[1:]):
                out.append(f"{rel}:{node.lineno} imports {_local(name)}")
    return out


@pytest.mark.parametrize("pkg", PACKAGES)
def test_no_private_name_is_imported_across_packages(pkg):
    assert [b for p in sorted((ROOT / pkg).rglob("*.py")) for b in _private_imports(p)] == []


def test_the_private_import_check_sees_one(tmp_path):
    (tmp_path / "sinks").mkdir()
    path = tmp_path / "sinks" / "probe.py"
    path.write_text("from bnptrack.tracker._lsap import solve\nfrom bnptrack.tracker import numerics, _x\n"
                    "from bnptrack.sinks._a import b\nimport bnptrack.pipeline._y\n")
    assert _private_imports(path, tmp_path) == ["sinks/probe.py:1 imports tracker._lsap.solve",
                                                "sinks/probe.py:2 imports tracker._x",
                                                "sinks/probe.py:4 imports pipeline._y"]


def _jitted_names(nodes: tuple[ast.AST, ...]) -> set[str]:
    """Functions compiled by numba: decorated with ``*jit``, or passed to a ``*jit(...)`` call."""
    names = set()
    for node in nodes:
        if isinstance(node, ast.Call) and "jit" in ast.unparse(node.func).lower():
            names |= {a.id for a in node.args if isinstance(a, ast.Name)}
        if isinstance(node, ast.FunctionDef) and any("jit" in ast.unparse(d).lower() for d in node.decorator_list):
            names.add(node.name)
    return names


def _rel(path: Path) -> str:
    return str(path.relative_to(ROOT)) if path.is_relative_to(ROOT) else path.name


def _long_functions(path: Path) -> list[str]:
    nodes = _nodes(path)
    kernels = _jitted_names(nodes)
    out = []
    for node in nodes:
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)) and node.name not in kernels:
            n = node.end_lineno - node.lineno + 1
            if n > MAX_FUNCTION_LINES:
                out.append(f"{_rel(path)}:{node.lineno} {node.name} ({n} lines)")
    return out


@pytest.mark.parametrize("pkg", PACKAGES)
def test_functions_stay_short(pkg):
    assert [f for p in sorted((ROOT / pkg).rglob("*.py")) for f in _long_functions(p)] == []


def test_the_size_rules_see_a_long_function(tmp_path):
    body = "\n".join(f"    x{i} = {i}" for i in range(61))
    path = tmp_path / "probe.py"
    path.write_text(f"def f():\n{body}\n\ndef k():\n{body}\n\nk2 = njit(k)\n")
    assert _long_functions(path) == ["probe.py:1 f (62 lines)"]


def _wide_kernels(path: Path) -> dict[str, int]:
    """Each numba kernel of ``path`` with more than :data:`MAX_KERNEL_ARGS` positional arguments:
    ``"file:name"`` -> its count."""
    nodes = _nodes(path)
    kernels = _jitted_names(nodes)
    return {f"{_rel(path)}:{node.name}": len(node.args.posonlyargs) + len(node.args.args)
            for node in nodes if isinstance(node, ast.FunctionDef) and node.name in kernels
            and len(node.args.posonlyargs) + len(node.args.args) > MAX_KERNEL_ARGS}


def test_kernel_arguments_are_bundled():
    """A kernel over the limit is listed with its exact count, which ratchets: a new wide kernel, a
    wider one, and one bundled (narrower, or within the limit) each fail until the list says so."""
    wide = {k: n for p in sorted((ROOT / "tracker").rglob("*.py")) for k, n in _wide_kernels(p).items()}
    assert wide == WIDE_KERNELS


def test_the_kernel_rule_sees_a_wide_kernel(tmp_path):
    args = ", ".join(f"a{i}" for i in range(MAX_KERNEL_ARGS + 1))
    path = tmp_path / "probe.py"
    path.write_text(f"def k({args}):\n    return a0\n\n\ndef f({args}):\n    return a0\n\n\nk = jit(k)\n")
    assert _wide_kernels(path) == {"probe.py:k": MAX_KERNEL_ARGS + 1}


def _layout_row(folder: str) -> str:
    text = (ROOT / "docs" / "architecture.md").read_text()
    rows = [line for line in text.splitlines() if line.startswith(f"| `{folder}/` |")]
    assert len(rows) == 1, f"docs/architecture.md's module map needs one row for {folder}/"
    return rows[0]


def _layout_paths(row: str) -> set[str]:
    """The paths a layout row names: a backticked ``name.py`` or ``dir/``; names inside the
    parentheses right after a ``dir/`` are in that folder (``bnp/ (filter.py, ...)``)."""
    stack: list[str | None] = []
    named, last_dir = set(), None
    for tok in re.finditer(r"`([A-Za-z_][\w]*\.py|[A-Za-z_]\w*/)`|\(|\)", row.split("|")[2]):
        text = tok.group(0)
        if text == "(":
            stack.append(last_dir)
        elif text == ")":
            stack.pop()
        else:
            path = next((d for d in reversed(stack) if d), "") + tok.group(1)
            named.add(path)
            last_dir = path if path.endswith("/") else None
            continue
        last_dir = None
    return named


def test_layout_paths_follow_the_parentheses():
    row = "| `x/` | `a.py` (`b.py`), `d/` (`c.py`, `e/` (`f.py`)), `g.py` |"
    assert _layout_paths(row) == {"a.py", "b.py", "d/", "d/c.py", "d/e/", "d/e/f.py", "g.py"}


@pytest.mark.parametrize("pkg", PACKAGES)
def test_the_module_map_names_every_module(pkg):
    """Every module and sub-package of ``pkg`` is named, at its path, in its row of the module
    map (docs/architecture.md), and the row names no path that does not exist."""
    named = _layout_paths(_layout_row(pkg))
    base = ROOT / pkg
    present = {str(p.relative_to(base)) for p in base.rglob("*.py") if p.name != "__init__.py"}
    present |= {str(p.relative_to(base)) + "/" for p in base.rglob("*")
                if p.is_dir() and p.name != "__pycache__"}
    assert sorted(present - named) == [], f"{pkg}/: not in the module map's row"
    assert sorted(named - present) == [], f"{pkg}/: the module map names what does not exist"


#: A line (with its backslash continuations) that could import a package by its bare name: a
#: package name after ``import`` or ``from``, not after a dot (``bnptrack.tracker``).  Files
#: without one hold no bare import and are not parsed.
_MAYBE_BARE = re.compile(r"\b(?:import|from)\b(?:[^\n]|\\\n)*?(?<![\w.])(?:tracker|pipeline|sources|sinks)\b")


def _bare_imports(path: Path) -> list[str]:
    """Imports of a project package by its bare folder name (``from tracker.x import y``)."""
    if not _MAYBE_BARE.search(path.read_text()):
        return []
    nodes = _nodes(path)
    names = [(a.name, n.lineno) for n in nodes if isinstance(n, ast.Import) for a in n.names]
    names += [(n.module or "", n.lineno) for n in nodes if isinstance(n, ast.ImportFrom) and not n.level]
    return [f"{_rel(path)}:{line} {name}" for name, line in names if name.split(".")[0] in PACKAGES]


def test_every_import_goes_through_the_bnptrack_namespace():
    """The installed distribution claims one top-level name, ``bnptrack``: a user's own
    ``tracker.py`` beside a notebook must not shadow the project's tracker package."""
    files = [p for d in (*PACKAGES, "bnptrack", "tests", "benchmarks") for p in sorted((ROOT / d).rglob("*.py"))]
    assert [b for p in files for b in _bare_imports(p)] == []


def test_the_bare_import_check_sees_one(tmp_path):
    path = tmp_path / "probe.py"
    path.write_text("import os\nfrom tracker.bnp import filter\nfrom bnptrack.sinks import sink\n")
    assert _bare_imports(path) == ["probe.py:2 tracker.bnp"]


def test_pyproject_installs_every_package_under_bnptrack():
    """pyproject.toml maps each folder to ``bnptrack.<folder>`` and lists every sub-package."""
    import tomllib

    setup = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]
    dirs = {"bnptrack": "bnptrack", **{f"bnptrack.{p}": p for p in PACKAGES}}
    assert setup["package-dir"] == dirs
    present = {"bnptrack"} | {
        "bnptrack." + ".".join(init.parent.relative_to(ROOT).parts)
        for pkg in PACKAGES for init in (ROOT / pkg).rglob("__init__.py")}
    assert sorted(setup["packages"]) == sorted(present)


_BARE_TEXT = re.compile(r"(?<![\w.])(?:from (?:tracker|pipeline|sources|sinks)(?:\.\w+)* import|import (?:tracker|pipeline|sources|sinks)\b)"
                        r"|-m (?:tracker|pipeline|sources|sinks)\b")


def _bare_in_text(path: Path) -> list[str]:
    """Bare imports written in text: Python code in strings (``python -c`` programs, subprocess
    argv) and in the documentation's code, e.g. ``from pipeline.view import screenshot``."""
    return [f"{_rel(path)}:{i} {m.group(0)}" for i, line in enumerate(path.read_text().splitlines(), 1)
            for m in _BARE_TEXT.finditer(line)]


def test_no_bare_import_hides_in_strings_or_docs():
    files = [p for d in (*PACKAGES, "bnptrack", "tests", "benchmarks") for p in sorted((ROOT / d).rglob("*.py"))
             if p.name != "test_architecture.py"]
    files += [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]
    assert [b for p in files for b in _bare_in_text(p)] == []


def test_the_text_check_sees_a_bare_import(tmp_path):
    path = tmp_path / "probe.md"
    path.write_text("x\n`from pipeline.view import screenshot`\npython3 -m pipeline track\nfrom bnptrack.tracker import y\n")
    assert _bare_in_text(path) == ["probe.md:2 from pipeline.view import", "probe.md:3 -m pipeline"]


@pytest.mark.slow  # a fresh interpreter: start-up and import machinery
def test_a_checkout_on_the_path_imports_its_own_folders(tmp_path):
    """``bnptrack/__init__.py`` of a source checkout puts that checkout's folders under
    ``bnptrack.``, so a second work tree on PYTHONPATH (an A/B baseline) runs its own code,
    not the installed copy's."""
    import shutil
    import subprocess
    import sys

    shutil.copytree(ROOT / "bnptrack", tmp_path / "bnptrack")
    (tmp_path / "pyproject.toml").write_text("")
    (tmp_path / "tracker").mkdir()
    (tmp_path / "tracker" / "__init__.py").write_text("WHERE = 'the other checkout'\n")
    code = "import bnptrack.tracker as t; print(t.WHERE)"
    out = subprocess.run([sys.executable, "-c", code], cwd="/", capture_output=True, text=True, timeout=60,
                         env={"PYTHONPATH": str(tmp_path), "PATH": "/usr/bin:/bin"})
    assert out.stdout.strip() == "the other checkout", out.stderr
