# Every figure of paper_figures/ (the paper's Figures 2-4 and ours); the figure of the choice
# of K comes with its rule select_k (k_selection.smk), the observability studies' with theirs.


rule figure_design_points:
    """Figure 2: five design disturbances of N(0, I_2) and the resulting (x~_1, z~_1) of model Same."""
    input:
        figure2_disturbances,
    output:
        pdf=report(
            f"{OUT}/fig2_design_points.pdf", caption="../report/fig2.rst", category="Figures"
        ),
        png=f"{OUT}/fig2_design_points.png",
    log:
        "results/shared/logs/figure_design_points.log",
    conda:
        "../../envs/ssmobs.yaml"
    params:
        figure=config["figure2"],
    script:
        "../scripts/figure_design_points.py"


rule figure_joint_vs_marginal:
    """Figure 3: joint- vs marginal-MAP estimates of (a, x0) of the scenarios of paper_outputs.figure3."""
    input:
        joint=[f"results/{n}/joint_map/joint_map.parquet" for n in FIGURE3_SCENARIOS],
        marginal=[f"results/{n}/gather_nuts/marginal_map.parquet" for n in FIGURE3_SCENARIOS],
    output:
        figure=report(
            multiext(f"{OUT}/fig3_joint_vs_marginal", ".pdf", ".png"),
            caption="../report/fig3.rst",
            category="Figures",
        ),
    log:
        "results/shared/logs/figure_joint_vs_marginal.log",
    localrule: True
    conda:
        "../../envs/ssmobs.yaml"
    params:
        scenarios=[SCENARIOS[n] for n in FIGURE3_SCENARIOS],
    script:
        "../scripts/figure_joint_vs_marginal.py"


rule figure_profile_posterior:
    """Figure 4: profile posterior of (a, x0) for trajectory k = 1 of paper_outputs.figure4."""
    input:
        "results/{scenario}/design_trajectories/trajectories.nc",
    output:
        figure=report(
            multiext(f"{OUT}/fig4_profile_posterior_{{scenario}}", ".pdf", ".png"),
            caption="../report/fig4.rst",
            category="Figures",
        ),
    log:
        "results/{scenario}/logs/figure_profile_posterior.log",
    conda:
        "../../envs/ssmobs.yaml"
    params:
        scenario=lambda wc: SCENARIOS[wc.scenario],
        grid=config["figure4"],
    script:
        "../scripts/figure_profile_posterior.py"


rule figure_observability:
    """|K^max|/K and |K^Stan|/K across all scenarios with 95 % intervals, ours beside the paper's."""
    input:
        summary=f"{OUT}/section4_summary.csv",
    output:
        figure=report(
            multiext(f"{OUT}/fig_observability_ratios", ".pdf", ".png"),
            caption="../report/observability.rst",
            category="Figures",
        ),
    log:
        "results/shared/logs/figure_observability.log",
    localrule: True
    conda:
        "../../envs/ssmobs.yaml"
    script:
        "../scripts/figure_observability.py"


rule figure_exact_vs_stan:
    """Stan + KDE marginal MAP against the exact one, trajectory by trajectory."""
    input:
        stan="results/{scenario}/gather_nuts/marginal_map.parquet",
        exact=lambda wc: exact_table(wc.scenario, SCENARIOS[wc.scenario]["K"]),
    output:
        figure=report(
            multiext(f"{OUT}/fig_exact_vs_stan_{{scenario}}", ".pdf", ".png"),
            caption="../report/exact_vs_stan.rst",
            category="Figures",
        ),
    log:
        "results/{scenario}/logs/figure_exact_vs_stan.log",
    localrule: True
    conda:
        "../../envs/ssmobs.yaml"
    params:
        scenario=lambda wc: SCENARIOS[wc.scenario],
    script:
        "../scripts/figure_exact_vs_stan.py"
