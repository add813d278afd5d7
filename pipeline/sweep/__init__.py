"""Parameter sweeps: simulate → replay → evaluate every point of a grid, on one core, a
process pool or a Dask cluster.

* The grid is the cartesian product of ``--param NAME=v1,v2,...`` over a scenario's parameters;
  every point is validated by the scenario's recorder before any work starts.
* Each point's seed is derived from the base seed and the point's parameters
  (:func:`point_seed`), so a point gives the same numbers on any executor and in any order.
* :func:`run_point` is the whole job of one point: a pure function of its :class:`PointTask`
  that never raises (an error comes back as text), so one failed point never loses the others.
* The client (this process) writes each point's metrics to ``points/<label>/metrics.parquet``
  as it completes, then ``point.json``, the record of what the point computed (every scenario
  parameter, runs, base and point seed, tracker subset, plugged trackers' specs and file
  hashes, package version). ``resume`` reuses a point only when both read back and the record
  is the task's; any other point is computed again and :attr:`SweepReport.notes` says what
  changed. :func:`check_resume` refuses to resume into a folder that holds another sweep.
* Interruption: Ctrl-C (``KeyboardInterrupt``) and SIGTERM/SIGHUP (:class:`SweepTerminated`,
  exit status 128 + signal) stop the workers, keep every finished point and remove the
  temporaries of the unfinished ones. Pool workers ignore SIGINT (the client stops them) and
  exit when the client dies, even by SIGKILL (Dask's nannied workers do the same); temporaries
  a SIGKILL leaves behind are removed by the next sweep into the folder, which holds a lock on
  it while it runs.
* Evaluation design values (the matching gate, the GOSPA cut-off and order, HOTA's distance
  scale, the SIAP gate: :attr:`trackreplay.stages.base.Stage.evaluation_defaults`) go with
  ``--set`` or ``--param`` like the trackers' design values: to every point's replay, without
  changing its seed. A name that is also a parameter of the scenario is the scenario's (it goes
  into the data set, whose scenario record the evaluation reads as well, and into the seed).
  Every point's ``point.json`` (and its ``metrics.parquet``'s metadata) records the evaluation
  values it was scored with; ``sweep.json`` and ``sweep.parquet``'s metadata the sweep's.
* Plugged trackers (``--tracker``) travel to the workers as canonical specs (absolute file
  paths, :func:`trackreplay.registry.canonical_spec`) and are loaded again there, so serial, process
  pool and Dask runs load the same file. A tracker that fails on a point is reported with its
  message (tracker, run, scan) while the other trackers' metrics of that point are kept.
* A point that fails, or is stopped, leaves nothing of its own: the files it wrote in its folder
  (data set, outputs, recording) are removed, and only those (:func:`discard_point_files`). A
  worker process that dies under a point is that point's failure; the other points finish
  (:func:`~trackreplay.sweep.executors._iter_process`; on Dask after its retries). A point whose files cannot be written (a
  full or read-only disk, a file size limit: :data:`trackreplay.paths.DISK_ERRNOS`) stops the
  whole sweep with one line naming the file, since every other point would fail the same way;
  finished points are kept for ``--resume``.
* Dask is the engine beyond one machine (``Client(address)``); locally a ``LocalCluster``
  whose scheduler, nannies and workers (and their HTTP routes, on a random port) listen on
  127.0.0.1 only, without dashboard. No home-made scheduler.

The package is split by role; its users import from ``trackreplay.sweep``, which holds the public
names of all of them:

=================  ==============================================================================
``grid``           ``--param`` parsing, :class:`PointTask` per point, its seed and label
``point``          :func:`run_point`: one point simulated, replayed and evaluated; its table rows
``executors``      serial, process pool (forkserver) and Dask; a worker's life and stop
``run``            :func:`run_sweep`: the points run, written as they finish, collected; spec sweeps
``resume``         which finished points are reused, and why the others are computed again
``outputs``        ``sweep.parquet`` / ``.csv`` / ``.json`` and the plots
``folder``         a point's files, temporaries, the folder lock, writes that name their file
``interruption``   SIGINT / SIGTERM / SIGHUP: :class:`SweepTerminated`, signals held back
``evaluation``     the evaluation design values: declared, checked, used, summarised
=================  ==============================================================================
"""

from trackreplay.sweep.evaluation import (EVALUATION_METADATA, check_evaluation_values, evaluation_defaults_of,
                                          evaluation_summary, evaluation_used)
from trackreplay.sweep.executors import EXECUTORS, PRELOAD, default_workers, local_cluster
from trackreplay.sweep.folder import POINT_FILES, discard_point_files
from trackreplay.sweep.grid import PointTask, build_grid, parse_param_specs, point_label, point_seed, scenario_families
from trackreplay.sweep.interruption import SweepTerminated
from trackreplay.sweep.outputs import write_sweep_outputs
from trackreplay.sweep.point import RECORD_COLUMNS, RECORD_SCHEMA, PointResult, run_point
from trackreplay.sweep.resume import check_resume, record_changes
from trackreplay.sweep.run import SweepReport, run_sweep, sweep_spec_report, sweep_spec_scenario

__all__ = ["EVALUATION_METADATA", "EXECUTORS", "POINT_FILES", "PRELOAD", "RECORD_COLUMNS", "RECORD_SCHEMA",
           "PointResult", "PointTask", "SweepReport", "SweepTerminated", "build_grid", "check_evaluation_values",
           "check_resume", "default_workers", "discard_point_files", "evaluation_defaults_of", "evaluation_summary",
           "evaluation_used", "local_cluster", "parse_param_specs", "point_label", "point_seed", "record_changes",
           "run_point", "run_sweep", "scenario_families", "sweep_spec_report", "sweep_spec_scenario",
           "write_sweep_outputs"]
