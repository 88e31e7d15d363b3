# Stage 1 (Sec. III.A): design disturbances and design trajectories.


rule design_disturbances:
    """K point-symmetric LCD design disturbances of N(0, I_q) (or a random baseline), shared by scenarios."""
    output:
        f"{DESIGN_DIR}/q{{q}}_K{{K}}_{{method}}_seed{{seed}}.nc",
    log:
        f"{DESIGN_DIR}/logs/q{{q}}_K{{K}}_{{method}}_seed{{seed}}.log",
    benchmark:
        f"{DESIGN_DIR}/benchmarks/q{{q}}_K{{K}}_{{method}}_seed{{seed}}.tsv"
    conda:
        "../../envs/ssmobs.yaml"
    threads: 1
    resources:
        mem_mb=4000,
        runtime=30,
    params:
        design=config["design"],
    script:
        "../scripts/design_disturbances.py"


rule design_trajectories:
    """Design state and observation trajectories x~(k), z~(k) of one scenario (Eq. (1)), at
    its K or at the exact stage's K (the key says which)."""
    input:
        unpack(
            lambda wc: PATHS.trajectory_inputs(
                wc.scenario, expect_key("trajectories", wc.scenario, wc.key)["K"]
            )
        ),
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
        scenario=lambda wc: {
            **SCENARIOS[wc.scenario],
            "K": expect_key("trajectories", wc.scenario, wc.key)["K"],
        },
    script:
        "../scripts/design_trajectories.py"
