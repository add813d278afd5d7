"""Stage processors: each consumes the channels it understands and emits channels in the same
data contract. ``replay`` discovers which stages apply from the channels a file holds.
See :class:`trackreplay.stages.base.Stage` for the interface.

A stage's module (and the trackers and numerics it imports) is loaded only when a file needs it:
which stage applies is known from its family's channels in :mod:`trackreplay.vocabulary`, so a
radar replay never imports the array or JPDA numerics (``docs/architecture.md``).
"""

from __future__ import annotations

import importlib

from trackreplay import vocabulary as vocab

# (stage name, measurement family, "module:Class"), read off the families' one declaration: a
# family's stage is named as the family
STAGE_CLASSES = tuple((f.name, f.name, f.stage) for f in vocab.FAMILIES.values())

_LOADED: dict = {}


def stage_named(name: str):
    """The stage called ``name``, its module imported on first use."""
    if name not in _LOADED:
        spec = next((s for n, _, s in STAGE_CLASSES if n == name), None)
        if spec is None:
            raise KeyError(f"no stage {name!r} (have: {', '.join(n for n, _, _ in STAGE_CLASSES)})")
        module, cls = spec.split(":")
        _LOADED[name] = getattr(importlib.import_module(module), cls)()
    return _LOADED[name]


def stages_named(names) -> list:
    """The stages among ``names``, in the registry's order."""
    names = set(names)
    return [stage_named(n) for n, _, _ in STAGE_CLASSES if n in names]


def applicable_stages(topics) -> list:
    """Stages whose input channels are all present."""
    topics = set(topics)
    return [stage_named(n) for n, family, _ in STAGE_CLASSES if set(vocab.FAMILIES[family].inputs) <= topics]


def stage_for_outputs(topics):
    """The stage that wrote a replay output file (from its output channels)."""
    for name, family, _ in STAGE_CLASSES:
        prefixes = vocab.FAMILIES[family].output_prefixes
        if any(t.startswith(prefixes) for t in topics):
            return stage_named(name)
    return None


def __getattr__(attribute: str):
    # every stage, for listings (`replay trackers`, sweeps): loads them all
    if attribute == "STAGES":
        return [stage_named(n) for n, _, _ in STAGE_CLASSES]
    raise AttributeError(f"module {__name__!r} has no attribute {attribute!r}")
