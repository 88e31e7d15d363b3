# Exact marginal posteriors (issue 11): Kalman filter with a diffuse x0 + grid over Omega,
# for the scenarios whose model is linear in the states.


rule exact_marginal:
    """Exact marginal MAP, 5 %/95 % quantiles and Definition 3 per trajectory, and the summary."""
    input:
        trajectories=lambda wc: PATHS.trajectories(
            wc.scenario, expect_key("exact", wc.scenario, wc.key)["K"]
        ),
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
        scenario=lambda wc: SCENARIOS[wc.scenario],
        settings=config["exact_marginal"],
    script:
        "../scripts/exact_marginal.py"
