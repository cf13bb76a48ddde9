"""Generic single-input systems (``t,u,y`` records): the paper's W block and its relatives.

- the models themselves — u → G₁ → f → G₂ → y (Wiener, Wiener–Hammerstein), the nonlinear feedback,
  the store chain, an output limit; streaming with a batch twin — are a floor below, in
  :mod:`rtlift.model.siso` (their file form: :mod:`rtlift.model.siso_file`);
- :mod:`.identify` — best linear approximation, pole/zero splits, joint refinement; the nonlinear
  feedback (:mod:`.feedback`) and the store chain (:mod:`.store_chain`), on the options and
  limits they share (:mod:`.common`);
- :mod:`.diagnose` — what the residual says the model lacks (``output_dynamics``), added with
  joint re-estimation and judged on held-out records.
"""
