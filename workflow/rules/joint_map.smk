# Stage 2 (Sec. III.B): joint MAP with the paper's numerical checks; choice of K (Sec. IV.A).


rule joint_map:
    """Joint MAP by a primal barrier method and the checks of Sec. III.B for every trajectory."""
    input:
        "results/{scenario}/design_trajectories/trajectories.nc",
    output:
        table="results/{scenario}/joint_map/joint_map.parquet",
        theta="results/{scenario}/joint_map/theta_hat.nc",
        summary="results/{scenario}/joint_map/summary.json",
    log:
        "results/{scenario}/logs/joint_map.log",
    benchmark:
        "results/{scenario}/benchmarks/joint_map.tsv"
    params:
        scenario=lambda wc: SCENARIOS[wc.scenario],
        settings=config["joint_map"],
    threads: 1
    resources:
        mem_mb=4000,
        runtime=60,
    conda:
        "../../envs/ssmobs.yaml"
    script:
        "../scripts/joint_map.py"


rule k_selection_point:
    """Joint-MAP summary V_{K_i} for one K_i, disturbance method, set variant and seed (Sec. IV.A)."""
    input:
        k_selection_disturbances,
    output:
        "results/k_selection/{ksel}/{method}_{sets}_seed{seed}/K{K}.json",
    log:
        "results/k_selection/{ksel}/logs/{method}_{sets}_seed{seed}_K{K}.log",
    params:
        scenario=lambda wc: SCENARIOS[KSEL[wc.ksel]["scenario"]],
        settings=config["joint_map"],
    threads: 1
    resources:
        mem_mb=4000,
        runtime=60,
    conda:
        "../../envs/ssmobs.yaml"
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
    params:
        ksel=lambda wc: KSEL[wc.ksel],
        scenario=lambda wc: SCENARIOS[KSEL[wc.ksel]["scenario"]],
    localrule: True
    conda:
        "../../envs/ssmobs.yaml"
    script:
        "../scripts/select_k.py"


rule table_k_selection:
    """Chosen K for every k_selection entry, method and seed, beside the paper's K."""
    input:
        [f"results/k_selection/{name}/selection.json" for name in KSEL],
    output:
        report(
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


rule figure_profile_posterior:
    """Figure 4: profile posterior of (a, x0) for trajectory k = 1 of ranWalk, T = 4."""
    input:
        "results/{scenario}/design_trajectories/trajectories.nc",
    output:
        report(
            multiext(f"{OUT}/fig4_profile_posterior_{{scenario}}", ".pdf", ".png"),
            caption="../report/fig4.rst",
            category="Figures",
        ),
    log:
        "results/{scenario}/logs/figure_profile_posterior.log",
    params:
        scenario=lambda wc: SCENARIOS[wc.scenario],
        grid=config["figure4"],
    conda:
        "../../envs/ssmobs.yaml"
    script:
        "../scripts/figure_profile_posterior.py"


rule joint_map_mu0_sweep:
    """|K^max|/K of the Sep models over barrier starts mu_0 (the gradient-balance rule first)."""
    input:
        trajectories=[f"results/{n}/design_trajectories/trajectories.nc" for n in MU0_SCENARIOS],
        paper_values="config/paper_values.yaml",
    output:
        report(
            multiext(f"{OUT}/table_mu0_sweep", ".csv", ".md", ".tex"),
            caption="../report/mu0_sweep.rst",
            category="Tables",
        ),
    log:
        "results/shared/logs/joint_map_mu0_sweep.log",
    params:
        trajectories={n: f"results/{n}/design_trajectories/trajectories.nc" for n in MU0_SCENARIOS},
        scenarios={n: SCENARIOS[n] for n in MU0_SCENARIOS},
        settings=config["joint_map"],
        mu0_per_T=config["mu0_sweep"]["mu0_per_T"],
    threads: 1
    resources:
        mem_mb=4000,
        runtime=120,
    conda:
        "../../envs/ssmobs.yaml"
    script:
        "../scripts/joint_map_mu0_sweep.py"
