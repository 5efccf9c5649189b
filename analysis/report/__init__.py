"""All analyses of a scenario in one report: what is computed (``settings``), the run and ``analysis.json``
(``build``), what the page says (``view``) and how it is laid out (``html``, ``templates/``).
"""
