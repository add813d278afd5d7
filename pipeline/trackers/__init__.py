"""Trackers: one module per paper, each the paper's loop over the numerical cores.

Every built-in tracker is a :class:`~trackreplay.trackers.interface.Tracker`, the interface a
user's plugged tracker implements (docs/trackers.md), and is run by its family's stage like any
other.

The paper index
---------------
Where each paper lives, from its data to its page (family names as in
``trackreplay.vocabulary.FAMILIES``; scenarios as ``replay scenarios`` lists them):

* **Track-while-scan radar α-β trackers** (Kim & Lee 2006), family ``radar-plots``, scenario
  ``radar-tws``: tracker ``trackers/radar_tws.py``; cores ``cores/filters/alpha_beta_gains.py``,
  ``kalman.py``, ``converted_measurements.py``, ``pcrb.py``; recorder ``recorders/radar_tws.py``;
  stage ``stages/radar_tws.py``; evaluator ``evaluators/radar_tws.py``; view
  ``face/rerun_radar_tws.py``; page ``docs/papers/radar-tws.md``. The family's many-target
  trackers (GNN, JPDA, and a UKF as a one-class filter strategy), scenario ``radar-multi``:
  ``trackers/radar_multi_target.py`` over ``cores/filters/track_filter.py``,
  ``cores/association/gating.py``, ``gnn.py``, ``jpda.py``, ``track_management.py``; recorder
  ``recorders/radar_multi.py``; measures ``evaluators/standard.py``, ``hota.py``, ``siap.py``,
  ``set_distances.py``.
* **Cross-correlation peaks in clutter, JPDA and amplitude-aided JPDA_A** (Park, Ryu & Lee 1994),
  family ``bearing-peaks``, scenarios ``xcorr-crossing`` and ``xcorr-maneuver``: tracker
  ``trackers/bearing_peaks.py`` (+ ``peak_roles.py``); cores ``cores/association/jpda.py``,
  ``peak_model_fit.py``, ``track_management.py``; recorders ``recorders/xcorr_peaks.py``,
  ``xcorr_signals.py``; stage ``stages/bearing_peaks.py``; evaluator
  ``evaluators/track_association.py``; view ``face/rerun_bearing_peaks.py``; commands
  ``face/cli_xcorr.py``; page ``docs/papers/bearing-peaks.md``.
* **Array snapshots to bearing tracks by the angular innovation** (Ryu, Lee & Lee 2001), family
  ``array-snapshots``, scenario ``array-crossing``: tracker ``trackers/array_bearing.py``; cores
  ``cores/array/`` (``linear_array.py``, ``music.py``, ``past_subspace.py``,
  ``angular_innovation.py``, ``wideband_count.py``, ``flop_counts.py``); recorders
  ``recorders/array_snapshots.py``, ``wav_array.py``; stage ``stages/array_bearing.py``; evaluator
  ``evaluators/array_bearing.py``; view ``face/rerun_array_bearing.py``; commands
  ``face/cli_array.py``; page ``docs/papers/array-bearing.md``.
* **TDOA/FDOA moving-emitter localisation by Gauss-Newton** (Kim et al. 2013), family
  ``tdoa-fdoa``, scenarios ``tdoa-fdoa`` and ``tdoa-fdoa-noise``: tracker ``trackers/emitter.py``;
  cores ``cores/localisation/`` (``tdoa_fdoa_model.py``, ``gauss_newton.py``,
  ``batched_least_squares.py``, ``crlb.py``, ``tdoa_fdoa_crlb.py``, ``cep_plane.py``,
  ``coarse_grid_search.py``); recorder ``recorders/tdoa_fdoa.py``; stage
  ``stages/emitter_localisation.py``; evaluator ``evaluators/emitter_localisation.py``; view
  ``face/rerun_emitter.py``; commands ``face/cli_emitter.py``; page ``docs/papers/tdoa-fdoa.md``.
* **Coloured measurement noise: AR(1) estimation, decorrelation, SRIF and IMMs** (Kwon 1997),
  family ``colored-position``, scenarios ``colored-ar``, ``colored-circle``, ``colored-imm``:
  tracker ``trackers/colored_noise.py``; cores ``cores/filters/ar1_estimation.py``,
  ``decorrelation.py``, ``srif.py``, ``imm.py``, ``kalman.py``, ``pcrb.py``; recorder
  ``recorders/colored_noise.py``; stage ``stages/colored_noise_imm.py``; evaluator
  ``evaluators/colored_noise_imm.py``; view ``face/rerun_colored_noise.py``; commands
  ``face/cli_colored_noise.py``; page ``docs/papers/colored-noise-imm.md``.

The paths are relative to the ``pipeline/`` folder, except ``recorders/``, ``evaluators/`` and
``docs/`` at the repository's top. One paper still carries several names (family, stage,
channel prefix); docs/architecture.md says which name is used where.
"""
