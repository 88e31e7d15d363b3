# Stage 2 (Sec. III.B): joint MAP with the paper's numerical checks, and its barrier starts.
# The choice of K (Sec. IV.A): k_selection.smk.


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
    conda:
        "../../envs/ssmobs.yaml"
    threads: 1
    resources:
        mem_mb=4000,
        runtime=60,
    params:
        scenario=lambda wc: SCENARIOS[wc.scenario],
        settings=config["joint_map"],
    script:
        "../scripts/joint_map.py"


rule joint_map_mu0_sweep:
    """|K^max|/K of the Sep models over barrier starts mu_0 (the gradient-balance rule first)."""
    input:
        trajectories=[f"results/{n}/design_trajectories/trajectories.nc" for n in MU0_SCENARIOS],
        paper_values="config/paper_values.yaml",
    output:
        table=report(
            multiext(f"{OUT}/table_mu0_sweep", ".csv", ".md", ".tex"),
            caption="../report/mu0_sweep.rst",
            category="Tables",
        ),
    log:
        "results/shared/logs/joint_map_mu0_sweep.log",
    conda:
        "../../envs/ssmobs.yaml"
    threads: 1
    resources:
        mem_mb=4000,
        runtime=120,
    params:
        scenarios=[SCENARIOS[n] for n in MU0_SCENARIOS],
        settings=config["joint_map"],
        mu0_per_T=config["mu0_sweep"]["mu0_per_T"],
    script:
        "../scripts/joint_map_mu0_sweep.py"
