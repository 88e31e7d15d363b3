"""Stage-level glue called by the workflow scripts: read inputs, compute, write outputs.

One module per stage, as in ``workflow/rules/``: :mod:`~ssmobs.stages.design` (Sec. III.A),
:mod:`~ssmobs.stages.joint_map` (Sec. III.B), :mod:`~ssmobs.stages.k_selection` (Sec. IV.A:
its grid and the choice of K from it), :mod:`~ssmobs.stages.stan` (Sec. III.C),
:mod:`~ssmobs.stages.exact` (issue 11), :mod:`~ssmobs.stages.observability_map` (issue 21)
and :mod:`~ssmobs.stages.outputs` (the paper's tables and figures, one module per subject).
Each function is what one Snakemake rule does, so a step can be rerun by hand by calling it
with the same paths; the numerics live in the modules it calls.

A rule's glue lives in a module hashed into the cache key that holds its outputs
(:mod:`ssmobs.stage_code`): the stamped tables and figures (``joint_map_mu0_sweep``,
``select_k``, ``table_k_selection`` among them) in modules of their own
(:mod:`ssmobs.stages.outputs`, :mod:`ssmobs.stages.k_selection.choice`), keyed by the
outputs' key, so that an edit of a table's glue never reruns the stage it reads.

Callers import from the stage module (``from ssmobs.stages.stan import run_sample_batch``);
this package imports none of them, so importing one stage runs no other stage's code.
"""

from __future__ import annotations

import os

#: a path argument of the stage functions
PathLike = str | os.PathLike
