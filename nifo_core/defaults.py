"""The analysis defaults nifo falls back on when neither the user, a model file nor the data say otherwise: one
home for each value (python-control's ``config.defaults``), imported by the estimator
(:mod:`nifo_core.nifo`), the settings merge (:mod:`nifo_core.settings`), the linear part
(:mod:`nifo_core.predict`), the command line's help and the identifier node's parameters.

It sits at the bottom of the core's layers (``.importlinter``): it imports nothing of nifo.
"""

__all__ = ["DEFAULT_ANALYSIS_BAND_HZ", "DEFAULT_COND_LIMIT"]

#: the analysis band when nothing else says [Hz] (the paper's figures and Table 2: 2-30 Hz)
DEFAULT_ANALYSIS_BAND_HZ = (2.0, 30.0)
#: scaled cond(G_UU) above which a line counts as ill-conditioned
DEFAULT_COND_LIMIT = 1e4
