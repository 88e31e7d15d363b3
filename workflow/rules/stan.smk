# Stage 3 (Sec. III.C): one NUTS run per design trajectory, convergence checks, marginal MAPs.


rule build_stan_model:
    """Compile stan/<model>.stan once with the configured backend (native, cmdstanpy, PyStan)."""
    input:
        lambda wc: str(REPO / "stan" / f"{wc.model}.stan"),
    output:
        "results/shared/stan/{backend}/{model}.json",
    log:
        "results/shared/logs/build_stan_model/{backend}/{model}.log",
    conda:
        "../../envs/ssmobs.yaml"
    resources:
        mem_mb=4000,
        runtime=30,
    params:
        backend=lambda wc: wc.backend,
    script:
        "../scripts/build_stan_model.py"


rule sample_nuts:
    """NUTS for one batch of trajectories; one record per trajectory, resumable."""
    input:
        trajectories="results/{scenario}/design_trajectories/trajectories.nc",
        marker=lambda wc: f"results/shared/stan/{STAN_BACKEND}/{SCENARIOS[wc.scenario]['model']}.json",
    output:
        "results/{scenario}/sample_nuts/batch{batch}.parquet",
    log:
        "results/{scenario}/logs/sample_nuts/batch{batch}.log",
    benchmark:
        "results/{scenario}/benchmarks/sample_nuts/batch{batch}.tsv"
    group:
        "nuts"
    conda:
        "../../envs/ssmobs.yaml"
    threads: 1
    resources:
        mem_mb=3000,
        runtime=lambda wc: 10 + 2 * SCENARIO_OBJECTS[wc.scenario].batch_size(config["stan"]),
    params:
        scenario=lambda wc: SCENARIOS[wc.scenario],
        stan=config["stan"],
        backend=STAN_BACKEND,
        convergence=config["convergence"],
        records="results/{scenario}/sample_nuts/records",
        draws="results/{scenario}/draws",
    script:
        "../scripts/sample_nuts.py"


rule gather_nuts:
    """All trajectories of a scenario: |K^Stan|, marginal-MAP mean/var/MSE, coverage, bias."""
    input:
        trajectories="results/{scenario}/design_trajectories/trajectories.nc",
        batches=nuts_batches,
    output:
        table="results/{scenario}/gather_nuts/marginal_map.parquet",
        summary="results/{scenario}/gather_nuts/summary.json",
    log:
        "results/{scenario}/logs/gather_nuts.log",
    conda:
        "../../envs/ssmobs.yaml"
    params:
        scenario=lambda wc: SCENARIOS[wc.scenario],
    script:
        "../scripts/gather_nuts.py"
