"""Seeing the results: the Rerun recording (live and offline) and the HTML report.

- :mod:`nifo.viz.results`: find and read the result directories the commands wrote;
- :mod:`nifo.viz.rerun_log`: one ``log_*`` function per entity subtree and the
  blueprint, shared by ``nifo view`` (offline) and the live viewer node;
- :mod:`nifo.viz.report_html`: the self-contained HTML report (``nifo report``).

rerun and matplotlib are imported only inside these modules' functions' callers
(the core never sees them).
"""
