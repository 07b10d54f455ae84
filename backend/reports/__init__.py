"""The calibration report: one self-contained HTML file for the whole rig.

:mod:`.gather` reads what the report shows from a session (accepted results, their captures, the solved
rig tree), :mod:`backend.plots` draws it with matplotlib (the same figures the studio shows), :mod:`.template` is
the Jinja2 page. :func:`backend.services.report.render_report` joins them.
"""
