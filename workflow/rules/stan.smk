# Stage 3 (Sec. III.C): one NUTS run per design trajectory, convergence checks, marginal MAPs.


rule build_stan_model:
    """Compile stan/<model>.stan (or the program generated from a model without one, or
    with analytic gradients, which this job alone writes) once with the configured backend
    (native, cmdstanpy, PyStan); the marker names the program the NUTS batches run."""
    input:
        lambda wc: keyed_input("program", wc.model, wc.key, PATHS.stan_source(wc.model)),
    output:
        "results/shared/stan/{backend}/{model}/{key}.json",
    log:
        "results/shared/stan/{backend}/{model}/{key}.log",
    conda:
        "../../envs/ssmobs.yaml"
    resources:
        mem_mb=4000,
        runtime=30,
    params:
        # of the inputs its key is made of (ssmobs.config.stage_inputs.ProgramInputs)
        backend=lambda wc: expect_key("program", wc.model, wc.key)["inputs"].backend,
        gradients=lambda wc: expect_key("program", wc.model, wc.key)["inputs"].gradients,
    script:
        "../scripts/build_stan_model.py"


rule sample_nuts:
    """NUTS for one batch of trajectories; one record per trajectory, resumable."""
    input:
        unpack(lambda wc: PATHS.stan_init_inputs(wc.scenario)),
        trajectories=lambda wc: keyed_input(
            "nuts_batches",
            wc.scenario,
            wc.key,
            PATHS.nuts_inputs(wc.scenario).record.trajectories,
        ),
        # the program it runs is the one this job built (the marker names it)
        marker=lambda wc: PATHS.nuts_inputs(wc.scenario).record.program,
        checked=lambda wc: PATHS.check(wc.scenario, stan=True),
    output:
        table="results/{scenario}/sample_nuts/{key}/batch{batch}.parquet",
    log:
        "results/{scenario}/sample_nuts/{key}/batch{batch}.log",
    benchmark:
        "results/{scenario}/sample_nuts/{key}/benchmark_batch{batch}.tsv"
    group:
        "nuts"
    conda:
        "../../envs/ssmobs.yaml"
    # the sampler's worker processes: NutsBatchesInputs.threads (config.stage_inputs)
    threads: 1
    resources:
        mem_mb=3000,
        runtime=lambda wc: 10 + 2 * PATHS.batch_size(wc.scenario),
    params:
        # what the stage reads, and its key is made of (ssmobs.config.stage_inputs)
        inputs=lambda wc: PATHS.inputs(
            "nuts_batches", wc.scenario, batch_size=PATHS.batch_size(wc.scenario)
        ),
    script:
        "../scripts/sample_nuts.py"


rule gather_nuts:
    """All trajectories of a scenario: |K^Stan| under the configured convergence checks,
    marginal-MAP mean/var/MSE, coverage, bias."""
    input:
        trajectories=lambda wc: keyed_input(
            "gather", wc.scenario, wc.key, PATHS.gather_inputs(wc.scenario).trajectories
        ),
        batches=lambda wc: PATHS.gather_inputs(wc.scenario).batches,
    output:
        table="results/{scenario}/gather_nuts/{key}/marginal_map.parquet",
        summary="results/{scenario}/gather_nuts/{key}/summary.json",
    log:
        "results/{scenario}/gather_nuts/{key}/gather_nuts.log",
    conda:
        "../../envs/ssmobs.yaml"
    params:
        # what the stage reads, and its key is made of (ssmobs.config.stage_inputs)
        inputs=lambda wc: PATHS.inputs(
            "gather", wc.scenario, batch_size=PATHS.batch_size(wc.scenario)
        ),
    script:
        "../scripts/gather_nuts.py"
