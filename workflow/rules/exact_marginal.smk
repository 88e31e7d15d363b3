# Exact marginal posteriors (issue 11): Kalman filter with a diffuse x0 + grid over Omega,
# for the scenarios whose model is linear in the states.


rule exact_design_trajectories:
    """Design trajectories of a scenario at the exact stage's K (when it differs from K)."""
    input:
        exact_disturbances,
    output:
        "results/{scenario}/exact_marginal/K{K}/trajectories.nc",
    log:
        "results/{scenario}/logs/exact_marginal/design_trajectories_K{K}.log",
    params:
        scenario=lambda wc: {**SCENARIOS[wc.scenario], "K": int(wc.K)},
    resources:
        mem_mb=2000,
        runtime=10,
    conda:
        "../../envs/ssmobs.yaml"
    script:
        "../scripts/design_trajectories.py"


rule exact_marginal:
    """Exact marginal MAP, 5 %/95 % quantiles and Definition 3 per trajectory, and the summary."""
    input:
        trajectories=exact_trajectories,
    output:
        table="results/{scenario}/exact_marginal/K{K}/marginal_map.parquet",
        summary="results/{scenario}/exact_marginal/K{K}/summary.json",
    log:
        "results/{scenario}/logs/exact_marginal/K{K}.log",
    benchmark:
        "results/{scenario}/benchmarks/exact_marginal/K{K}.tsv"
    params:
        scenario=lambda wc: SCENARIOS[wc.scenario],
    threads: 1
    resources:
        mem_mb=4000,
        runtime=60,
    conda:
        "../../envs/ssmobs.yaml"
    script:
        "../scripts/exact_marginal.py"


rule figure_exact_vs_stan:
    """Stan + KDE marginal MAP against the exact one, trajectory by trajectory."""
    input:
        stan="results/{scenario}/gather_nuts/marginal_map.parquet",
        exact=lambda wc: exact_table(wc.scenario, SCENARIOS[wc.scenario]["K"]),
    output:
        report(
            multiext(f"{OUT}/fig_exact_vs_stan_{{scenario}}", ".pdf", ".png"),
            caption="../report/exact_vs_stan.rst",
            category="Figures",
        ),
    log:
        "results/{scenario}/logs/figure_exact_vs_stan.log",
    params:
        scenario=lambda wc: SCENARIOS[wc.scenario],
    localrule: True
    conda:
        "../../envs/ssmobs.yaml"
    script:
        "../scripts/figure_exact_vs_stan.py"
