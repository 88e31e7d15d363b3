# Every figure of paper_figures/ (the paper's Figures 2-4 and ours); the figure of the choice
# of K comes with its rule select_k (k_selection.smk), the observability studies' with theirs.
# Which figures a config makes, the files each reads, what it reads beside them (params
# inputs) and its stamp's key: PATHS.stamped_outputs (ssmobs.config.stage_inputs.stamped).


rule figure_design_points:
    """Figure 2: five design disturbances of N(0, I_2) and the resulting (x~_1, z~_1) of model Same."""
    input:
        unpack(stamped_files("figure_design_points")),
    output:
        pdf=report(
            f"{OUT}/fig2_design_points.pdf", caption="../report/fig2.rst", category="Figures"
        ),
        png=f"{OUT}/fig2_design_points.png",
        stamp=PATHS.stamp("figure_design_points"),
    log:
        f"results/outputs/{OUT}/logs/figure_design_points.log",
    conda:
        "../../envs/ssmobs.yaml"
    params:
        inputs=stamped_inputs,
        key=stamp_key,
    script:
        "../scripts/figure_design_points.py"


rule figure_joint_vs_marginal:
    """Figure 3: joint- vs marginal-MAP estimates of (a, x0) of the scenarios of paper_outputs.figure3."""
    input:
        unpack(stamped_files("figure_joint_vs_marginal")),
    output:
        figure=report(
            multiext(f"{OUT}/fig3_joint_vs_marginal", ".pdf", ".png"),
            caption="../report/fig3.rst",
            category="Figures",
        ),
        stamp=PATHS.stamp("figure_joint_vs_marginal"),
    log:
        f"results/outputs/{OUT}/logs/figure_joint_vs_marginal.log",
    localrule: True
    conda:
        "../../envs/ssmobs.yaml"
    params:
        inputs=stamped_inputs,
        key=stamp_key,
    script:
        "../scripts/figure_joint_vs_marginal.py"


rule figure_profile_posterior:
    """Figure 4: profile posterior of (a, x0) for trajectory k = 1 of paper_outputs.figure4."""
    input:
        unpack(stamped_files("figure_profile_posterior_{scenario}")),
    output:
        figure=report(
            multiext(f"{OUT}/fig4_profile_posterior_{{scenario}}", ".pdf", ".png"),
            caption="../report/fig4.rst",
            category="Figures",
        ),
        stamp=PATHS.stamp("figure_profile_posterior_{scenario}"),
    log:
        f"results/outputs/{OUT}/logs/figure_profile_posterior_{{scenario}}.log",
    conda:
        "../../envs/ssmobs.yaml"
    params:
        inputs=stamped_inputs,
        key=stamp_key,
    script:
        "../scripts/figure_profile_posterior.py"


rule figure_observability:
    """|K^max|/K and |K^Stan|/K across all scenarios with 95 % intervals, ours beside the paper's."""
    input:
        unpack(stamped_files("figure_observability")),
    output:
        figure=report(
            multiext(f"{OUT}/fig_observability_ratios", ".pdf", ".png"),
            caption="../report/observability.rst",
            category="Figures",
        ),
        stamp=PATHS.stamp("figure_observability"),
    log:
        f"results/outputs/{OUT}/logs/figure_observability.log",
    localrule: True
    conda:
        "../../envs/ssmobs.yaml"
    params:
        inputs=stamped_inputs,
        key=stamp_key,
    script:
        "../scripts/figure_observability.py"


rule figure_exact_vs_stan:
    """Stan + KDE marginal MAP against the exact one, trajectory by trajectory."""
    input:
        unpack(stamped_files("figure_exact_vs_stan_{scenario}")),
    output:
        figure=report(
            multiext(f"{OUT}/fig_exact_vs_stan_{{scenario}}", ".pdf", ".png"),
            caption="../report/exact_vs_stan.rst",
            category="Figures",
        ),
        table=multiext(f"{OUT}/exact_vs_stan_{{scenario}}", ".csv", ".md"),
        stamp=PATHS.stamp("figure_exact_vs_stan_{scenario}"),
    log:
        f"results/outputs/{OUT}/logs/figure_exact_vs_stan_{{scenario}}.log",
    localrule: True
    conda:
        "../../envs/ssmobs.yaml"
    params:
        inputs=stamped_inputs,
        key=stamp_key,
    script:
        "../scripts/figure_exact_vs_stan.py"
