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
    """Joint-MAP summary V_{K_i} for one K_i, disturbance method and seed (Sec. IV.A)."""
    input:
        k_selection_disturbances,
    output:
        "results/k_selection/{ksel}/{method}_seed{seed}/K{K}.json",
    log:
        "results/k_selection/{ksel}/logs/{method}_seed{seed}_K{K}.log",
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
