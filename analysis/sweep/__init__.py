"""Parameter sweeps, a kind of job: the sweep file (``spec``), running it (``runner``) and its summary
(``summary``).
"""
