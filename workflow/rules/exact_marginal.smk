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
    conda:
        "../../envs/ssmobs.yaml"
    resources:
        mem_mb=2000,
        runtime=10,
    params:
        scenario=lambda wc: {**SCENARIOS[wc.scenario], "K": int(wc.K)},
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
    conda:
        "../../envs/ssmobs.yaml"
    threads: 1
    resources:
        mem_mb=4000,
        runtime=60,
    params:
        scenario=lambda wc: SCENARIOS[wc.scenario],
    script:
        "../scripts/exact_marginal.py"
