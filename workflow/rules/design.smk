# Stage 1 (Sec. III.A): design disturbances and design trajectories.


rule design_disturbances:
    """K point-symmetric LCD design disturbances of N(0, I_q) (or a random baseline), shared by scenarios."""
    output:
        f"{PATHS.design_dir}/q{{q}}_K{{K}}_{{method}}_seed{{seed}}.nc",
    log:
        f"{PATHS.design_dir}/logs/q{{q}}_K{{K}}_{{method}}_seed{{seed}}.log",
    benchmark:
        f"{PATHS.design_dir}/benchmarks/q{{q}}_K{{K}}_{{method}}_seed{{seed}}.tsv"
    conda:
        "../../envs/ssmobs.yaml"
    threads: 1
    resources:
        mem_mb=4000,
        runtime=30,
    params:
        # the design block as its inputs give it, what the design key is made of
        # (ssmobs.config.stage_inputs.DesignSetsInputs)
        design=KEYS.design_inputs.design_config,
    script:
        "../scripts/design_disturbances.py"


rule design_trajectories:
    """Design state and observation trajectories x~(k), z~(k) of one scenario (Eq. (1)), at
    its K or at the exact stage's K (the key says which)."""
    input:
        # the design set the stage reads (TrajectoriesInputs.design_set)
        disturbances=lambda wc: PATHS.design_set(
            wc.scenario, expect_key("trajectories", wc.scenario, wc.key)["K"]
        ),
        checked=lambda wc: PATHS.check(wc.scenario),
    output:
        trajectories="results/{scenario}/design_trajectories/{key}/trajectories.nc",
        checksum="results/{scenario}/design_trajectories/{key}/trajectories.nc.sha256",
    log:
        "results/{scenario}/design_trajectories/{key}/design_trajectories.log",
    conda:
        "../../envs/ssmobs.yaml"
    resources:
        mem_mb=2000,
        runtime=10,
    params:
        # what the stage reads, and its key is made of (ssmobs.config.stage_inputs)
        inputs=lambda wc: PATHS.inputs(
            "trajectories", wc.scenario, K=expect_key("trajectories", wc.scenario, wc.key)["K"]
        ),
    script:
        "../scripts/design_trajectories.py"
