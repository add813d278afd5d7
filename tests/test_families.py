"""A family is declared once, and has one name from scenario to doc page (docs/architecture.md).

The declaration is :data:`trackreplay.vocabulary.FAMILIES`. A family's own files are named by its
stem (its name with ``-`` written ``_``): ``pipeline/stages/<stem>.py``,
``pipeline/face/rerun_<stem>.py``, and where the paper has them ``evaluators/<stem>.py``,
``pipeline/face/cli_<stem>.py``, ``pipeline/trackers/<stem>*.py``, ``recorders/<stem>*.py`` and
``docs/papers/<name>.md``. The registries of stages, built-in trackers, Rerun views and paper
commands are read off the declaration, and no other module of the package names a family: so a
new family costs four files (its entry in the declaration, its stage, its view, its tests), which
``test_a_new_family_costs_four_files`` counts.
"""

from __future__ import annotations

import ast
import functools
import importlib
import importlib.util
from pathlib import Path

import pytest

from trackreplay import vocabulary as vocab

ROOT = Path(__file__).resolve().parents[1]
FAMILIES = list(vocab.FAMILIES.values())
PACKAGE_FOLDERS = ("pipeline", "recorders", "evaluators")


def _own_files(family) -> set[Path]:
    """The files that are the family's own: named by its stem."""
    stem = family.stem
    own = {ROOT / "pipeline" / "vocabulary.py"}  # the declaration
    for folder, pattern in (("pipeline/stages", f"{stem}.py"), ("pipeline/face", f"rerun_{stem}*.py"),
                            ("pipeline/face", f"cli_{stem}.py"), ("evaluators", f"{stem}.py"),
                            ("pipeline/trackers", f"{stem}*.py"), ("recorders", f"{stem}*.py")):
        own |= set((ROOT / folder).glob(pattern))
    return own


@functools.lru_cache(maxsize=None)
def _strings_in(path: Path) -> tuple[tuple[int, str], ...]:
    """(line, value) of every string constant in ``path`` (each file parsed once)."""
    tree = ast.parse(path.read_text(), filename=str(path))
    return tuple((node.lineno, node.value) for node in ast.walk(tree)
                 if isinstance(node, ast.Constant) and isinstance(node.value, str))


def _names_in(path: Path, names: set[str]) -> list[tuple[int, str]]:
    """(line, name) of every string constant in ``path`` that is exactly one of ``names``."""
    return [(line, value) for line, value in _strings_in(path) if value in names]


@pytest.mark.parametrize("family", FAMILIES, ids=lambda f: f.name)
def test_one_name_per_paper(family):
    stem = family.stem
    module, cls = family.stage.split(":")
    stage = getattr(importlib.import_module(module), cls)
    assert (stage.name, stage.family) == (family.name, family.name)
    assert (ROOT / "pipeline" / "stages" / f"{stem}.py").is_file()
    assert (ROOT / "pipeline" / "face" / f"rerun_{stem}.py").is_file()
    assert (ROOT / "evaluators" / f"{stem}.py").is_file()
    assert (ROOT / "docs" / "papers" / f"{family.name}.md").is_file()
    assert family.output_prefix == f"/tracks/{family.name}/"
    assert (ROOT / "pipeline" / "face" / f"cli_{stem}.py").is_file() == family.commands
    for tracker_module in family.tracker_modules:
        assert tracker_module.startswith(stem) and (ROOT / "pipeline" / "trackers" / f"{tracker_module}.py").is_file()
    assert family.scenario == family.name or family.scenario.startswith(family.name + "-")


def test_every_bundled_scenario_is_named_after_its_family():
    from trackreplay.recorders.scenarios import available_scenarios

    names = available_scenarios()
    assert names and all(any(n == f.name or n.startswith(f.name + "-") for f in FAMILIES) for n in names), names


def test_the_registries_are_read_off_the_declaration():
    from trackreplay.face import cli
    from trackreplay.face.rerun_views import VIEW_MODULES
    from trackreplay.registry import BUILTIN_FAMILY_MODULES
    from trackreplay.stages import STAGE_CLASSES

    names = [f.name for f in FAMILIES]
    assert [n for n, _, _ in STAGE_CLASSES] == names
    assert list(VIEW_MODULES) == names and list(BUILTIN_FAMILY_MODULES) == names
    assert [m for m in cli.EXTENSION_MODULES if m.rsplit(".", 1)[1][len("cli_"):] in {f.stem for f in FAMILIES}] == [
        f.command_module for f in FAMILIES if f.commands]


def test_no_module_outside_a_family_s_own_files_names_it():
    """No hidden per-family branch: a family's name (or a former one) as a string appears only in
    the declaration and the family's own files."""
    found = []
    for family in FAMILIES:
        names = {family.name, *family.former_names}
        own = _own_files(family)
        for folder in PACKAGE_FOLDERS:
            for path in sorted((ROOT / folder).rglob("*.py")):
                if path not in own:
                    found += [f"{path.relative_to(ROOT)}:{line} names {name!r}" for line, name in _names_in(path, names)]
    assert not found, "\n".join(found)


def _module_file(module: str) -> Path:
    spec = importlib.util.find_spec(module.split(":")[0])
    return Path(spec.origin).resolve()


def test_a_new_family_costs_four_files():
    """What the machinery needs of a family beyond its paper's own code (trackers may be plugged,
    evaluators and recorders are optional): its entry in the declaration, the stage and the view
    the declaration names, and its tests. With no module outside them naming the family (the test
    above), that is every file a new family touches."""
    for family in FAMILIES:
        needed = {_module_file("trackreplay.vocabulary"), _module_file(family.stage), _module_file(family.view)}
        assert len(needed) == 3 and all(p.is_file() for p in needed)
        print(f"{family.name}: {len(needed) + 1} files (declaration, stage, view, tests)")
