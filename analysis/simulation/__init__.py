"""Analyses from nonlinear simulations: the paper's experiment (``experiment``), its Figures 4-8 and Table 3
(``figures``), and the gain and noise studies (``studies``).
"""
