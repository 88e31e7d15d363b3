# Stage 1 (Sec. III.A): design disturbances and design trajectories.


rule design_disturbances:
    """K point-symmetric LCD design disturbances of N(0, I_q) (or a random baseline), shared by scenarios."""
    output:
        "results/shared/design_disturbances/q{q}_K{K}_{method}_seed{seed}.nc",
    log:
        "results/shared/logs/design_disturbances/q{q}_K{K}_{method}_seed{seed}.log",
    benchmark:
        "results/shared/benchmarks/design_disturbances/q{q}_K{K}_{method}_seed{seed}.tsv"
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
    """Design state and observation trajectories x~(k), z~(k) of one scenario (Eq. (1))."""
    input:
        scenario_disturbances,
        checked=model_check,
    output:
        "results/{scenario}/design_trajectories/trajectories.nc",
    log:
        "results/{scenario}/logs/design_trajectories.log",
    conda:
        "../../envs/ssmobs.yaml"
    resources:
        mem_mb=2000,
        runtime=10,
    params:
        scenario=lambda wc: SCENARIOS[wc.scenario],
    script:
        "../scripts/design_trajectories.py"
