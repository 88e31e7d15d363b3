# The choice of K by relative differences (Sec. IV.A): one job per grid (method, set variant,
# seed) scoring V_{K_i} for every K_i; the RD rule over them; the table of the choices.


rule k_selection_grid:
    """Joint-MAP summaries V_{K_i} for every K_i of one disturbance method, set variant and
    seed (Sec. IV.A); the sets are made in the job, every point is cached as it finishes."""
    output:
        grid="results/k_selection/{ksel}/{key}/{method}_{sets}_seed{seed}.json",
    log:
        "results/k_selection/{ksel}/{key}/{method}_{sets}_seed{seed}.log",
    conda:
        "../../envs/ssmobs.yaml"
    threads: 1
    resources:
        mem_mb=4000,
        runtime=120,
    params:
        # what the stage reads, and its key is made of (ssmobs.config.stage_inputs)
        inputs=lambda wc: keyed_input(
            "k_selection_grid", wc.ksel, wc.key, PATHS.inputs("k_selection_grid", wc.ksel)
        ),
    script:
        "../scripts/k_selection_grid.py"


for _name in PATHS.k_selections:
    register_stamp(
        f"select_k_{_name}",
        [*PATHS.k_selection_grids(_name), "config/paper_values.yaml"],
        PATHS.select_k_params(_name),
    )


rule select_k:
    """The smallest K_i whose V_{K_i} agrees with all larger K_j within (c1, c2), per method."""
    input:
        grids=lambda wc: PATHS.k_selection_grids(wc.ksel),
        paper_values="config/paper_values.yaml",
    output:
        json="results/k_selection/{ksel}/selection.json",
        csv="results/k_selection/{ksel}/v_vectors.csv",
        figure=report(
            multiext(f"{OUT}/fig_k_convergence_{{ksel}}", ".pdf", ".png"),
            caption="../report/k_convergence.rst",
            category="Figures",
        ),
        stamp=PATHS.stamp("select_k_{ksel}"),
    log:
        "results/k_selection/{ksel}/select_k.log",
    localrule: True
    conda:
        "../../envs/ssmobs.yaml"
    params:
        ksel=lambda wc: PATHS.select_k_params(wc.ksel)["ksel"],
        scenario=lambda wc: PATHS.select_k_params(wc.ksel)["scenario"],
        key=stamp_key,
    script:
        "../scripts/select_k.py"


# the selections are stamped files: their stamps' keys key the table; made for this
# config's k_selection entries, or (empty) with the paper's outputs
if PATHS.k_selections or PATHS.paper_outputs:
    register_stamp(
        "table_k_selection",
        [PATHS.selection(name) for name in PATHS.k_selections],
        [STAMPS[PATHS.stamp(f"select_k_{name}")] for name in PATHS.k_selections],
    )


rule table_k_selection:
    """Chosen K for every k_selection entry, method and seed, beside the paper's K, and how
    often each K was chosen over the seeds."""
    input:
        [PATHS.selection(name) for name in PATHS.k_selections],
    output:
        table=report(
            multiext(f"{OUT}/table_k_selection", ".csv", ".md", ".tex"),
            caption="../report/k_selection.rst",
            category="Tables",
        ),
        distribution=multiext(f"{OUT}/table_k_selection_distribution", ".csv", ".md", ".tex"),
        stamp=PATHS.stamp("table_k_selection"),
    log:
        f"results/outputs/{OUT}/logs/table_k_selection.log",
    localrule: True
    conda:
        "../../envs/ssmobs.yaml"
    params:
        key=stamp_key,
    script:
        "../scripts/table_k_selection.py"
