"""The calibration report: one self-contained HTML file for the whole rig.

:mod:`.gather` reads what the report shows from a session (accepted results, their captures, the solved
rig tree), :mod:`.plots` draws it with matplotlib as inline images, :mod:`.template` is the Jinja2 page.
:func:`backend.services.report.render_report` joins them.
"""
