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

Metrics live in the top-level package ``evaluators``, simulators and converters in
``recorders``. See ``docs/architecture.md``.
"""

__version__ = "0.1.0"
