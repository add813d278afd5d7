"""trackreplay: offline replay and evaluation of target-tracking algorithms.

MCAP data sets go in; tracker outputs (MCAP), a Rerun recording and polars metrics tables come
out. The package is layered, and ``tests/test_architecture.py`` keeps the layers apart:

* :mod:`trackreplay.vocabulary` and :mod:`trackreplay.contract`: the data contract (what: channels,
  families, output vocabulary, flags; how: MCAP frames on disk);
* ``trackreplay.cores``: numerical cores by role (``filters``, ``association``, ``array``,
  ``localisation``), numpy/scipy functions of arrays batched over runs, no I/O, no timing;
* ``trackreplay.trackers``: the tracker interface (``interface.py``) and one module per paper's
  trackers, built on the cores;
* ``trackreplay.stages``: one thin stage per measurement family (decode channels, call trackers,
  score the arrays);
* :mod:`trackreplay.registry` (where trackers come from), :mod:`trackreplay.replay` (one replay),
  :mod:`trackreplay.sweep` (parameter grids on serial, process-pool or Dask executors);
* ``trackreplay.face``: the ``replay`` command line, Rerun views and the viewer; no numerics.

Metrics live in :mod:`trackreplay.evaluators`, simulators and converters in
:mod:`trackreplay.recorders` (the repository keeps them in its top-level folders ``evaluators/``
and ``recorders/``; the installed package has one top-level name). See ``docs/architecture.md``.

A plugged tracker starts with ``from trackreplay import Tracker, Param`` (``docs/trackers.md``).
"""

__version__ = "0.1.0"

# the public way in for a plugged tracker; loaded on first use, so that ``replay --help`` (which
# imports this package) does not pay for numpy
_PUBLIC = {"Tracker": "trackreplay.trackers.interface", "Param": "trackreplay.trackers.interface",
           "TrackerError": "trackreplay.trackers.interface", "vocabulary": "trackreplay.vocabulary"}
__all__ = ["Tracker", "Param", "TrackerError", "vocabulary", "__version__"]


def __getattr__(name: str):
    if name in _PUBLIC:
        import importlib

        module = importlib.import_module(_PUBLIC[name])
        return module if name == "vocabulary" else getattr(module, name)
    raise AttributeError(f"module 'trackreplay' has no attribute {name!r}")
