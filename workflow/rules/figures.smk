# Every figure of paper_figures/ (the paper's Figures 2-4 and ours); the figure of the choice
# of K comes with its rule select_k (k_selection.smk), the observability studies' with theirs.

# the paper's figures where the config asks for them (PATHS.paper_outputs); the figure draws
# model Same's trajectories: its module keys the figure too
if PATHS.paper_outputs:
    register_stamp(
        "figure_design_points",
        [PATHS.figure2_disturbances()],
        {"figure": config["figure2"], "model_code": KEYS.model_code("same")},
    )


rule figure_design_points:
    """Figure 2: five design disturbances of N(0, I_2) and the resulting (x~_1, z~_1) of model Same."""
    input:
        PATHS.figure2_disturbances(),
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
        figure=config["figure2"],
        key=stamp_key,
    script:
        "../scripts/figure_design_points.py"


if PATHS.paper_outputs:
    register_stamp(
        "figure_joint_vs_marginal",
        [
            *map(PATHS.joint_table, PATHS.figure3_scenarios),
            *map(PATHS.stan_table, PATHS.figure3_scenarios),
        ],
        [PATHS.scenario_entry(n) for n in PATHS.figure3_scenarios],
    )


rule figure_joint_vs_marginal:
    """Figure 3: joint- vs marginal-MAP estimates of (a, x0) of the scenarios of paper_outputs.figure3."""
    input:
        joint=[PATHS.joint_table(n) for n in PATHS.figure3_scenarios],
        marginal=[PATHS.stan_table(n) for n in PATHS.figure3_scenarios],
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
        scenarios=[PATHS.scenario_entry(n) for n in PATHS.figure3_scenarios],
        key=stamp_key,
    script:
        "../scripts/figure_joint_vs_marginal.py"


if PATHS.figure4_scenario:
    register_stamp(
        f"figure_profile_posterior_{PATHS.figure4_scenario}",
        [PATHS.trajectories(PATHS.figure4_scenario)],
        {"scenario": PATHS.scenario_entry(PATHS.figure4_scenario), "grid": config["figure4"]},
    )


rule figure_profile_posterior:
    """Figure 4: profile posterior of (a, x0) for trajectory k = 1 of paper_outputs.figure4."""
    input:
        lambda wc: PATHS.trajectories(wc.scenario),
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
        scenario=lambda wc: PATHS.scenario_entry(wc.scenario),
        grid=config["figure4"],
        key=stamp_key,
    script:
        "../scripts/figure_profile_posterior.py"


# its input is a stamped table: the table's key keys the figure
if PATHS.paper_outputs:
    register_stamp(
        "figure_observability", [f"{OUT}/section4_summary.csv"], STAMPS[PATHS.stamp("paper_tables")]
    )


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
        stamp=PATHS.stamp("figure_observability"),
    log:
        f"results/outputs/{OUT}/logs/figure_observability.log",
    localrule: True
    conda:
        "../../envs/ssmobs.yaml"
    params:
        key=stamp_key,
    script:
        "../scripts/figure_observability.py"


for _name in PATHS.exact_vs_stan_scenarios:
    register_stamp(
        f"figure_exact_vs_stan_{_name}",
        list(PATHS.exact_vs_stan_inputs(_name).values()),
        PATHS.scenario_entry(_name),
    )


rule figure_exact_vs_stan:
    """Stan + KDE marginal MAP against the exact one, trajectory by trajectory."""
    input:
        unpack(lambda wc: PATHS.exact_vs_stan_inputs(wc.scenario)),
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
        scenario=lambda wc: PATHS.scenario_entry(wc.scenario),
        key=stamp_key,
    script:
        "../scripts/figure_exact_vs_stan.py"
