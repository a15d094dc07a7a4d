"""The identified model and its prediction (docs/method.md §4): linear part, time simulation, refinement.

Modules:

- :mod:`nifo_core.predict.linear_part`  the linear part: a one-mass body or a stable rational fit of T21
- :mod:`nifo_core.predict.timesim`  the prediction engine: the model simulated in time
- :mod:`nifo_core.predict.fixed_point`  the frequency-domain fast path, where it provably converges
- :mod:`nifo_core.predict.timesim_lanes`  several models of one record marched together (the same bits)
- :mod:`nifo_core.predict.model`  ``IdentifiedModel`` and ``predict_body``
- :mod:`nifo_core.predict.time_prediction`  the time-domain prediction: a model's input, simulation, divergence
- :mod:`nifo_core.predict.feedback_paths`  terms with a bounded remainder through their own feedback paths
- :mod:`nifo_core.predict.prediction_error`  band NMSE of a prediction
- :mod:`nifo_core.predict.whole_signal`  the raw predicted signal's error over all frequencies, and the distortion
- :mod:`nifo_core.predict.scope`  what a model carries besides its dynamics: offsets, prediction band, validity
- :mod:`nifo_core.predict.output_signal`  the predicted signal in the output's unit, offset included
- :mod:`nifo_core.predict.scope_fit`  the static part, prediction band and validity from the identification records
- :mod:`nifo_core.predict.refine`  output-error refinement of a model's coefficients
- :mod:`nifo_core.predict.refine_bias`  the refinement's bias from sensor noise removed (errors in variables)
- :mod:`nifo_core.predict.heldout`  held-out parts and their scores
- :mod:`nifo_core.predict.prediction_bounds`  prediction bounds from the parameters' covariance
- :mod:`nifo_core.predict.model_fit`  the model classes the loop and identify fit

Layer: it imports :mod:`nifo_core.nifo`, :mod:`nifo_core.simulate`, :mod:`nifo_core.settings` and below
(``.importlinter``). The names below are its front door; the modules' private (``_``) names stay inside the package.

The front door is lazy (``lazy_loader``, as :mod:`nifo_core.signal`'s): a name's module is imported when the name
is first used, so importing one module of the package does not import the others.
"""

import lazy_loader

__getattr__, __dir__, __all__ = lazy_loader.attach(__name__, submod_attrs={
    "linear_part": ["BodyModel", "LinearPart", "RecordLines", "absorbed_rates", "fit_body_model", "fit_rational",
                    "nominal_linear_part", "pole_residue_response", "select_linear_part"],
    "timesim": ["TimeResponse", "discretise", "simulate_response"],
    "timesim_lanes": ["simulate_responses"],
    "time_prediction": ["predict_bodies", "predict_records"],
    "fixed_point": ["contraction_bound", "fixed_point_solve"],
    "model": ["IdentifiedModel", "Prediction", "PredictedTransmissibility", "PredictionDivergedError",
              "predict_body", "predict_transmissibility", "record_inputs"],
    "feedback_paths": ["PATH_KINDS", "SMALL_SLOPE", "JointFit", "PathFit", "PathResult", "check_terms",
                       "choose_paths", "equivalent_gammas", "fit_joint", "fit_paths", "path_model",
                       "path_remainders", "regimes_stable"],
    "prediction_error": ["band_spectra", "band_nmse"],
    "whole_signal": ["WholeSignalError", "whole_signal_error", "DistortionError", "distortion_error", "excited_lines"],
    "scope": ["Offsets", "PredictionBand", "Validity", "RecordValidity"],
    "output_signal": ["MeasuredOutput", "measured_output", "predicted_output", "output_name"],
    "scope_fit": ["fit_scope"],
    "refine": ["Refinement", "refine_model", "refine_jointly", "model_nmse", "parameter_space", "start_up_samples"],
    "heldout": ["HeldOut", "split_records", "Scores"],
    "prediction_bounds": ["PredictionSpread", "prediction_spread", "line_spread", "half_width", "Z95"],
    "model_fit": ["Fitted", "JointPathResult", "LinearChoice", "choose_linear_form", "fit_linear", "fit_model",
                  "joint_paths", "path_eligible"],
})
