"""The Figure-2 loop linearized: poles and mismatch (``loop``), any arm's derivatives (``arm_terms``,
``arm_linear``), observer bandwidth over the workspace (``bandwidth``), gain design (``gain_design``),
disturbance-rejection frequency responses (``frequency``), the sampled loop (``digital``) and their figures.
"""
