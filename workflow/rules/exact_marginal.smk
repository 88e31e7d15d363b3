# Exact marginal posteriors (issue 11): Kalman filter with a diffuse x0 + grid over Omega,
# for the scenarios whose model is linear in the states.


rule exact_marginal:
    """Exact marginal MAP, 5 %/95 % quantiles and Definition 3 per trajectory, and the summary."""
    input:
        trajectories=lambda wc: PATHS.inputs(
            "exact", wc.scenario, K=expect_key("exact", wc.scenario, wc.key)["K"]
        ).trajectories,
    output:
        table="results/{scenario}/exact_marginal/{key}/marginal_map.parquet",
        summary="results/{scenario}/exact_marginal/{key}/summary.json",
    log:
        "results/{scenario}/exact_marginal/{key}/exact_marginal.log",
    benchmark:
        "results/{scenario}/exact_marginal/{key}/benchmark.tsv"
    conda:
        "../../envs/ssmobs.yaml"
    threads: 1
    resources:
        mem_mb=4000,
        runtime=60,
    params:
        # what the stage reads, and its key is made of (ssmobs.config.stage_inputs)
        inputs=lambda wc: PATHS.inputs(
            "exact", wc.scenario, K=expect_key("exact", wc.scenario, wc.key)["K"]
        ),
    script:
        "../scripts/exact_marginal.py"
