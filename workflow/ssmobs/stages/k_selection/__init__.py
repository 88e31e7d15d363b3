"""Glue of the choice of K (Sec. IV.A): the joint-MAP summaries V_{K_i} of every K_i of a grid
(:mod:`~ssmobs.stages.k_selection.grid`, keyed as the grid) and the choice of K from them with
its figure and table (:mod:`~ssmobs.stages.k_selection.choice`, stamped outputs keyed by the
outputs' key).  Each module is hashed whole into its own key, so an edit of the choice never
reruns the grid.
"""
