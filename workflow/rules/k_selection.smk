# The choice of K by relative differences (Sec. IV.A): one joint-MAP summary V_{K_i} per
# K_i, method, set variant and seed; the RD rule over them; the table of the choices.


rule k_selection_point:
    """Joint-MAP summary V_{K_i} for one K_i, disturbance method, set variant and seed (Sec. IV.A)."""
    input:
        k_selection_disturbances,
    output:
        "results/k_selection/{ksel}/{method}_{sets}_seed{seed}/K{K}.json",
    log:
        "results/k_selection/{ksel}/logs/{method}_{sets}_seed{seed}_K{K}.log",
    conda:
        "../../envs/ssmobs.yaml"
    threads: 1
    resources:
        mem_mb=4000,
        runtime=60,
    params:
        scenario=lambda wc: SCENARIOS[KSEL[wc.ksel]["scenario"]],
        settings=config["joint_map"],
    script:
        "../scripts/k_selection_point.py"


rule select_k:
    """The smallest K_i whose V_{K_i} agrees with all larger K_j within (c1, c2), per method."""
    input:
        points=lambda wc: k_selection_points(KSEL[wc.ksel]),
        paper_values="config/paper_values.yaml",
    output:
        json="results/k_selection/{ksel}/selection.json",
        csv="results/k_selection/{ksel}/v_vectors.csv",
        figure=report(
            multiext(f"{OUT}/fig_k_convergence_{{ksel}}", ".pdf", ".png"),
            caption="../report/k_convergence.rst",
            category="Figures",
        ),
    log:
        "results/k_selection/{ksel}/logs/select_k.log",
    localrule: True
    conda:
        "../../envs/ssmobs.yaml"
    params:
        ksel=lambda wc: KSEL[wc.ksel],
        scenario=lambda wc: SCENARIOS[KSEL[wc.ksel]["scenario"]],
    script:
        "../scripts/select_k.py"


rule table_k_selection:
    """Chosen K for every k_selection entry, method and seed, beside the paper's K."""
    input:
        [f"results/k_selection/{name}/selection.json" for name in KSEL],
    output:
        table=report(
            multiext(f"{OUT}/table_k_selection", ".csv", ".md", ".tex"),
            caption="../report/k_selection.rst",
            category="Tables",
        ),
    log:
        "results/shared/logs/table_k_selection.log",
    localrule: True
    conda:
        "../../envs/ssmobs.yaml"
    script:
        "../scripts/table_k_selection.py"
