"""Trackers: one module per paper, each the paper's loop over the numerical cores.

Every built-in tracker is a :class:`~trackreplay.trackers.interface.Tracker`, the interface a
user's plugged tracker implements (docs/trackers.md), and is run by its family's stage like any
other.

The paper index
---------------
Where each paper lives, from its data to its page. Each paper has one name, its family's (as
declared in ``trackreplay.vocabulary.FAMILIES``): the name of its stage and of its outputs'
channels (``/tracks/<name>/<tracker>``), the first word of its scenarios, and the stem of its
modules and page (``tests/test_families.py`` holds it so):

* **Track-while-scan radar α-β trackers** (Kim & Lee 2006), family ``radar``, scenario
  ``radar-tws``: tracker ``trackers/radar_tws.py``; cores ``cores/filters/alpha_beta_gains.py``,
  ``kalman.py``, ``converted_measurements.py``, ``pcrb.py``; recorder ``recorders/radar_tws.py``;
  stage ``stages/radar.py``; evaluator ``evaluators/radar.py``; view
  ``face/rerun_radar.py``; page ``docs/papers/radar.md``. The family's many-target
  trackers (GNN, JPDA, and a UKF as a one-class filter strategy), scenario ``radar-multi``:
  ``trackers/radar_multi_target.py`` over ``cores/filters/track_filter.py``,
  ``cores/association/gating.py``, ``gnn.py``, ``jpda.py``, ``track_management.py``; recorder
  ``recorders/radar_multi.py``; measures ``evaluators/standard.py``, ``hota.py``, ``siap.py``,
  ``set_distances.py``.
* **Cross-correlation peaks in clutter, JPDA and amplitude-aided JPDA_A** (Park, Ryu & Lee 1994),
  family ``xcorr``, scenarios ``xcorr-crossing`` and ``xcorr-maneuver``: tracker
  ``trackers/xcorr.py`` (+ ``xcorr_peak_roles.py``); cores ``cores/association/jpda.py``,
  ``peak_model_fit.py``, ``track_management.py``; recorders ``recorders/xcorr_peaks.py``,
  ``xcorr_signals.py``; stage ``stages/xcorr.py``; evaluator
  ``evaluators/xcorr.py``; view ``face/rerun_xcorr.py``; commands
  ``face/cli_xcorr.py``; page ``docs/papers/xcorr.md``.
* **Array snapshots to bearing tracks by the angular innovation** (Ryu, Lee & Lee 2001), family
  ``array``, scenario ``array-crossing``: tracker ``trackers/array.py``; cores
  ``cores/array/`` (``linear_array.py``, ``music.py``, ``past_subspace.py``,
  ``angular_innovation.py``, ``wideband_count.py``, ``flop_counts.py``); recorders
  ``recorders/array_snapshots.py``, ``array_wav.py``; stage ``stages/array.py``; evaluator
  ``evaluators/array.py``; view ``face/rerun_array.py``; commands
  ``face/cli_array.py``; page ``docs/papers/array.md``.
* **TDOA/FDOA moving-emitter localisation by Gauss-Newton** (Kim et al. 2013), family
  ``tdoa-fdoa``, scenarios ``tdoa-fdoa`` and ``tdoa-fdoa-noise``: tracker ``trackers/tdoa_fdoa.py``;
  cores ``cores/localisation/`` (``tdoa_fdoa_model.py``, ``gauss_newton.py``,
  ``batched_least_squares.py``, ``crlb.py``, ``tdoa_fdoa_crlb.py``, ``cep_plane.py``,
  ``coarse_grid_search.py``); recorder ``recorders/tdoa_fdoa.py``; stage
  ``stages/tdoa_fdoa.py``; evaluator ``evaluators/tdoa_fdoa.py``; view
  ``face/rerun_tdoa_fdoa.py``; commands ``face/cli_tdoa_fdoa.py``; page ``docs/papers/tdoa-fdoa.md``.
* **Coloured measurement noise: AR(1) estimation, decorrelation, SRIF and IMMs** (Kwon 1997),
  family ``colored``, scenarios ``colored-ar``, ``colored-circle``, ``colored-imm``:
  tracker ``trackers/colored.py``; cores ``cores/filters/ar1_estimation.py``,
  ``decorrelation.py``, ``srif.py``, ``imm.py``, ``kalman.py``, ``pcrb.py``; recorder
  ``recorders/colored_noise.py``; stage ``stages/colored.py``; evaluator
  ``evaluators/colored.py``; view ``face/rerun_colored.py``; commands
  ``face/cli_colored.py``; page ``docs/papers/colored.md``.

The paths are relative to the ``pipeline/`` folder, except ``recorders/``, ``evaluators/`` and
``docs/`` at the repository's top. Input channels keep the names the data contract gives them
(``/radar/plots``, ``/emitter/measurements``, …: docs/contract.md).
"""
