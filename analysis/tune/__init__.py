"""Gain tuning, a kind of job: the tuning file (``spec``), evaluating candidates (``evaluate``, with the
linear constraints of ``linear`` and the responses of ``response``), the search (``runner``), what it writes
(``results``) and its report section (``report``); built-in tunings in ``tunings/``.
"""
