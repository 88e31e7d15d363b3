# Stage 2 (Sec. III.B): joint MAP with the paper's numerical checks, and its barrier starts.
# The choice of K (Sec. IV.A): k_selection.smk.


rule joint_map:
    """Joint MAP by a primal barrier method and the checks of Sec. III.B for every trajectory."""
    input:
        lambda wc: keyed_input(
            "joint_map", wc.scenario, wc.key, PATHS.inputs("joint_map", wc.scenario).trajectories
        ),
    output:
        table="results/{scenario}/joint_map/{key}/joint_map.parquet",
        theta="results/{scenario}/joint_map/{key}/theta_hat.nc",
        summary="results/{scenario}/joint_map/{key}/summary.json",
    log:
        "results/{scenario}/joint_map/{key}/joint_map.log",
    benchmark:
        "results/{scenario}/joint_map/{key}/benchmark.tsv"
    conda:
        "../../envs/ssmobs.yaml"
    threads: 1
    resources:
        mem_mb=4000,
        runtime=60,
    params:
        # what the stage reads, and its key is made of (ssmobs.config.stage_inputs)
        inputs=lambda wc: PATHS.inputs("joint_map", wc.scenario),
    script:
        "../scripts/joint_map.py"


# the paper's table, where the config asks for the paper's outputs: the files it reads, what
# it reads beside them and its stamp's key: PATHS.stamped_outputs


rule joint_map_mu0_sweep:
    """|K^max|/K of the Sep models over barrier starts mu_0 (the gradient-balance rule first)."""
    input:
        unpack(stamped_files("table_mu0_sweep")),
    output:
        table=report(
            multiext(f"{OUT}/table_mu0_sweep", ".csv", ".md", ".tex"),
            caption="../report/mu0_sweep.rst",
            category="Tables",
        ),
        stamp=PATHS.stamp("table_mu0_sweep"),
    log:
        f"results/outputs/{OUT}/logs/joint_map_mu0_sweep.log",
    conda:
        "../../envs/ssmobs.yaml"
    threads: 1
    resources:
        mem_mb=4000,
        runtime=120,
    params:
        inputs=stamped_inputs,
        key=stamp_key,
    script:
        "../scripts/joint_map_mu0_sweep.py"
