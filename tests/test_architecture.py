"""The layout stays true: import rules between the folders (see docs/architecture.md).

* numerical cores (``pipeline/cores``) and per-paper trackers (``pipeline/trackers``) import none
  of mcap, rerun, click, polars, matplotlib or dask, do no timing and no file I/O, and know nothing
  of stages, the face, the contract's file layer or the evaluators;
* stages are thin: no Rerun, click or plotting;
* evaluators read outputs through the contract and its vocabulary only: no cores, trackers or
  stages;
* the face (CLI, Rerun) does no numerics of its own: no scipy.
"""

from __future__ import annotations

import ast
from functools import lru_cache
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]

FRAMEWORKS = {"mcap", "mcap_protobuf", "rerun", "click", "polars", "matplotlib", "dask", "distributed"}
TIMING_AND_IO = {"time", "timeit", "io", "tempfile", "shutil", "pathlib", "os"}
THREADS_AND_PROCESSES = {"threading", "_thread", "concurrent", "multiprocessing", "asyncio", "subprocess", "signal"}
NUMERIC_INTERNALS = {"trackreplay.contract", "trackreplay.stages", "trackreplay.face", "trackreplay.replay", "trackreplay.sweep",
                     "trackreplay.evaluators", "trackreplay.recorders"}

RULES = {
    "pipeline/cores": FRAMEWORKS | TIMING_AND_IO | THREADS_AND_PROCESSES | NUMERIC_INTERNALS | {"trackreplay.trackers"},
    "pipeline/trackers": FRAMEWORKS | TIMING_AND_IO | THREADS_AND_PROCESSES | NUMERIC_INTERNALS,
    "pipeline/stages": {"rerun", "click", "matplotlib", "dask", "distributed", "trackreplay.face", "trackreplay.sweep"},
    "evaluators": {"trackreplay.cores", "trackreplay.trackers", "trackreplay.stages", "trackreplay.face", "rerun", "click"},
    "pipeline/face": {"scipy"},
}
# the import-free vocabulary, the interface and the small-matrix linear algebra (numpy only) are what
# cores, trackers and evaluators may use
# the installed package ``trackreplay`` maps its subpackages onto the repository's top-level folders
# (pyproject.toml's package-dir): trackreplay.recorders -> recorders/, trackreplay.evaluators ->
# evaluators/, everything else of trackreplay -> pipeline/
FOLDER_OF_PACKAGE = {"trackreplay.recorders": "recorders", "trackreplay.evaluators": "evaluators",
                     "trackreplay": "pipeline"}
ALLOWED_EVERYWHERE = {"trackreplay.vocabulary", "trackreplay.errors", "trackreplay.trackers.interface", "trackreplay.batched_linalg"}


@lru_cache(maxsize=None)
def _imports(path: Path) -> list[tuple[int, str]]:
    """(line, module) of every import in ``path``, function-level ones included; names imported
    from a package that are modules of their own count as those modules; imports under
    ``if TYPE_CHECKING:`` (annotations only, never run) do not count."""
    tree = ast.parse(path.read_text(), filename=str(path))
    skipped = {id(n) for node in ast.walk(tree) if isinstance(node, ast.If) and _is_type_checking(node.test)
               for inner in node.body for n in ast.walk(inner)}
    found = []
    for node in ast.walk(tree):
        if id(node) in skipped:
            continue
        if isinstance(node, ast.Import):
            found += [(node.lineno, a.name) for a in node.names]
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            found.append((node.lineno, node.module))
            found += [(node.lineno, f"{node.module}.{a.name}") for a in node.names
                      if _module_file(f"{node.module}.{a.name}") is not None]
    return found


def _is_type_checking(test) -> bool:
    return (isinstance(test, ast.Name) and test.id == "TYPE_CHECKING") or (
        isinstance(test, ast.Attribute) and test.attr == "TYPE_CHECKING")


def _module_file(module: str) -> Path | None:
    """The repository file of a module of ours (``trackreplay`` and its subpackages)."""
    package = next((p for p in FOLDER_OF_PACKAGE if module == p or module.startswith(p + ".")), None)
    if package is None:
        return None
    base = ROOT.joinpath(FOLDER_OF_PACKAGE[package], *module[len(package):].split(".")[1:])
    for candidate in (base.with_suffix(".py"), base / "__init__.py"):
        if candidate.is_file():
            return candidate
    return None


def _reached(path: Path) -> list[tuple[str, tuple[str, ...]]]:
    """Every module ``path`` reaches, directly or through modules of ours, with the chain of our
    modules that leads there (empty for a direct import)."""
    found, seen, todo = [], {path}, [(path, ())]
    while todo:
        here, via = todo.pop()
        for _, module in _imports(here):
            found.append((module, via))
            target = _module_file(module)
            if target is not None and target not in seen:
                seen.add(target)
                todo.append((target, via + (module,)))
    return found


def _forbidden(module: str, rule: set[str]) -> bool:
    if module in ALLOWED_EVERYWHERE or module == "trackreplay":
        return False
    return any(module == f or module.startswith(f + ".") for f in rule)


def _files(folder: str):
    return sorted((ROOT / folder).rglob("*.py"))


@pytest.mark.parametrize("folder", sorted(RULES))
def test_import_rules(folder):
    assert _files(folder), f"{folder} holds no modules"
    broken = [f"{p.relative_to(ROOT)}:{line} imports {mod}" for p in _files(folder) for line, mod in _imports(p)
              if _forbidden(mod, RULES[folder])]
    assert not broken, "\n".join(broken)


# what a folder may not reach even through modules of ours (a core reaching a thread or a file
# through a helper breaks its rule as much as importing it): the same rules, except that a stage
# may call an evaluator that draws (figures live with the evaluators) and the face, the top,
# reaches everything below it
REACH_RULES = {folder: rule for folder, rule in RULES.items() if folder != "pipeline/face"}
REACH_RULES["pipeline/stages"] = RULES["pipeline/stages"] - {"matplotlib"}


@pytest.mark.parametrize("folder", sorted(REACH_RULES))
def test_import_rules_hold_through_every_module_reached(folder):
    broken = sorted({f"{p.relative_to(ROOT)} → {' → '.join(via)} → {module}" for p in _files(folder)
                     for module, via in _reached(p) if via and _forbidden(module, REACH_RULES[folder])})
    assert not broken, "\n".join(broken)


@pytest.mark.parametrize("folder", ["pipeline/cores", "pipeline/trackers"])
def test_cores_and_trackers_open_no_files(folder):
    calls = []
    for p in _files(folder):
        for node in ast.walk(ast.parse(p.read_text())):
            if isinstance(node, ast.Call) and isinstance(node.func, ast.Name) and node.func.id in ("open", "print"):
                calls.append(f"{p.relative_to(ROOT)}:{node.lineno} calls {node.func.id}()")
    assert not calls, "\n".join(calls)


def test_docstrings_cite_nothing_outside_the_repository():
    # a user's clone has no folder of the specs or of the original papers: cite the paper and docs/
    outside = [f"{'shared'}/{name}" for name in ("spec", "seeds")]  # spelled apart: this file cites neither
    bad = [f"{p.relative_to(ROOT)}" for folder in ("pipeline", "recorders", "evaluators", "benchmarks", "examples",
                                                    "tests")
           for p in _files(folder) if any(ref in p.read_text() for ref in outside)]
    assert not bad, "cite docs/ and the paper, not a folder outside the repository: " + ", ".join(bad)


def test_every_cited_document_exists():
    # a citation of docs/... must lead somewhere in the clone
    import re

    cited = re.compile(r"docs/[\w\-/]+\.md")
    missing = sorted({f"{p.relative_to(ROOT)} → {ref}"
                      for folder in ("pipeline", "recorders", "evaluators", "benchmarks", "examples", "tests", "data")
                      for p in _files(folder) for ref in cited.findall(p.read_text())
                      if not (ROOT / ref).is_file()})
    assert not missing, "cited documents that do not exist: " + "; ".join(missing)


def test_the_rules_catch_a_violation(tmp_path):
    # the checker itself can fail: a core that imports polars and times itself is caught
    core = tmp_path / "bad_core.py"
    core.write_text("import time\nimport polars as pl\nfrom trackreplay import vocabulary\n"
                    "from typing import TYPE_CHECKING\nif TYPE_CHECKING:\n    import os\n")
    found = [m for _, m in _imports(core) if _forbidden(m, RULES["pipeline/cores"])]
    assert found == ["time", "polars"]
    # and indirectly: a core that imports a module of ours which starts threads is caught, with
    # the chain that leads there
    helper = ROOT / "pipeline" / "stack_threads.py"
    indirect = tmp_path / "bad_core_through_a_helper.py"
    indirect.write_text("from trackreplay import stack_threads\n")
    reached = {(m, via) for m, via in _reached(indirect) if via and _forbidden(m, RULES["pipeline/cores"])}
    assert helper.is_file() and ("concurrent.futures", ("trackreplay.stack_threads",)) in reached


def test_every_relative_link_in_the_documentation_exists():
    import re

    link = re.compile(r"\]\(([^)#\s]+)(?:#[^)]*)?\)")
    missing = []
    for md in [ROOT / "README.md", *sorted((ROOT / "docs").rglob("*.md"))]:
        for target in link.findall(md.read_text()):
            if "://" in target or target.startswith("mailto:"):
                continue
            if not (md.parent / target).exists():
                missing.append(f"{md.relative_to(ROOT)} → {target}")
    assert not missing, "broken links: " + "; ".join(missing)


def test_the_paper_index_names_files_that_exist():
    # the trackers package's docstring maps each paper to its files; a bare name lives in the
    # folder of the path before it
    import re

    import trackreplay.trackers

    missing, folder = [], None
    for name in re.findall(r"``([\w/]+\.(?:py|md)|[\w/]+/)``", trackreplay.trackers.__doc__):
        if "/" in name:
            folder = name if name.endswith("/") else name.rsplit("/", 1)[0] + "/"
            path = name
        else:
            path = folder + name
        if not any((base / path).exists() for base in (ROOT / "pipeline", ROOT)):
            missing.append(path)
    assert folder is not None and not missing, f"the paper index names missing files: {missing}"
