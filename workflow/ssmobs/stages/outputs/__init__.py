"""Glue of the tables and figures (rules in ``workflow/rules/outputs.smk`` and
``workflow/rules/figures.smk``) and of every other rule that writes a stamped output into
``outputs_dir``, one module per subject: the paper's tables and the convergence
sensitivity (:mod:`~ssmobs.stages.outputs.paper_tables`), the figures
(:mod:`~ssmobs.stages.outputs.figures`) and the table of barrier starts
(:mod:`~ssmobs.stages.outputs.mu0_sweep`); the choice of K's figure and table are with its
grid (:mod:`ssmobs.stages.k_selection.choice`).

All of them are keyed together by the outputs' key (:meth:`ssmobs.cache_keys.CacheKeys.output`),
so an edit here reruns the tables and figures, never the stages they read.
"""
