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


# the choice of K and its table: which a config makes, the files each reads, what it reads
# beside them and its stamp's key: PATHS.stamped_outputs (ssmobs.config.stage_inputs.stamped)


rule select_k:
    """The smallest K_i whose V_{K_i} agrees with all larger K_j within (c1, c2), per method."""
    input:
        unpack(stamped_files("select_k_{ksel}")),
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
        inputs=stamped_inputs,
        key=stamp_key,
    script:
        "../scripts/select_k.py"


# the selections are stamped files: their stamps' keys key the table; made for this config's
# k_selection entries, or (empty) with the paper's outputs


rule table_k_selection:
    """Chosen K for every k_selection entry, method and seed, beside the paper's K, and how
    often each K was chosen over the seeds."""
    input:
        unpack(stamped_files("table_k_selection")),
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
        inputs=stamped_inputs,
        key=stamp_key,
    script:
        "../scripts/table_k_selection.py"
