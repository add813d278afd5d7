"""Submodules that a dependency imports but a replay never uses, loaded on first use instead.

scipy (1.17) imports its vendored array-API layer with every submodule, and that layer runs
``from numpy import *``. numpy 2 lists ``f2py`` in ``numpy.__all__`` and imports it lazily, so
the star import loads numpy's Fortran wrapper generator, which in turn imports
``charset_normalizer`` and compiles its Fortran-parsing regular expressions: 0.08–0.15 s of every
replay's start-up, for a module nothing in a replay calls (``docs/benchmarks.md``).

:func:`defer` puts a finder first on :data:`sys.meta_path` that hands such a module to the
standard library's :class:`importlib.util.LazyLoader`: the import succeeds at once, the
module's code runs on the first attribute access, and from then on it is the ordinary module.
Nothing changes for code that does use it.
"""

from __future__ import annotations

import importlib.abc
import importlib.util
import sys

#: Loaded only when an attribute of theirs is used.
DEFERRED_MODULES = frozenset({"numpy.f2py"})


class _DeferringFinder(importlib.abc.MetaPathFinder):
    """Finds a deferred module through the other finders and wraps its loader in a LazyLoader."""

    def __init__(self, names: frozenset):
        self.names = names

    def find_spec(self, fullname, path, target=None):
        if fullname not in self.names:
            return None
        for finder in sys.meta_path:
            if finder is self or not hasattr(finder, "find_spec"):
                continue
            spec = finder.find_spec(fullname, path, target)
            if spec is not None:
                if spec.loader is not None and hasattr(spec.loader, "exec_module"):
                    spec.loader = importlib.util.LazyLoader(spec.loader)
                return spec
        return None


def defer(names: frozenset = DEFERRED_MODULES) -> None:
    """Load ``names`` on first use from now on in this process (once; modules already loaded stay).

    Called by the command line before anything imports numpy or scipy; a library user's process
    is left as it is.
    """
    if not any(isinstance(f, _DeferringFinder) for f in sys.meta_path):
        sys.meta_path.insert(0, _DeferringFinder(names))
