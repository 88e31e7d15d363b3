# Stage 4: the paper's tables and figures in paper_figures/ (ours beside the paper's values).


rule paper_tables:
    """Tables II, III and the Section IV summary as CSV, Markdown and LaTeX."""
    input:
        joint=[joint_summary(n) for n in JOINT_SCENARIOS],
        marginal=[stan_summary(n) for n in STAN_SCENARIOS],
        exact=[exact_summary_path(n) for n in EXACT_SCENARIOS],
        paper_values="config/paper_values.yaml",
    output:
        report(
            multiext(f"{OUT}/table2_joint_vs_marginal", ".csv", ".md", ".tex"),
            caption="../report/table2.rst",
            category="Tables",
        ),
        report(
            multiext(f"{OUT}/table3_coverage", ".csv", ".md", ".tex"),
            caption="../report/table3.rst",
            category="Tables",
        ),
        report(
            multiext(f"{OUT}/section4_summary", ".csv", ".md", ".tex"),
            caption="../report/section4.rst",
            category="Tables",
        ),
    log:
        "results/shared/logs/paper_tables.log",
    params:
        scenarios=config["scenarios"],
        joint={n: joint_summary(n) for n in JOINT_SCENARIOS},
        marginal={n: stan_summary(n) for n in STAN_SCENARIOS},
        exact={n: exact_summary_path(n) for n in EXACT_SCENARIOS},
    localrule: True
    conda:
        "../../envs/ssmobs.yaml"
    script:
        "../scripts/paper_tables.py"


rule figure_joint_vs_marginal:
    """Figure 3: joint- vs marginal-MAP estimates of (a, x0), model Same, (0.9, 8)."""
    input:
        joint=[f"results/{n}/joint_map/joint_map.parquet" for n in TABLE_II_SCENARIOS],
        marginal=[f"results/{n}/gather_nuts/marginal_map.parquet" for n in TABLE_II_SCENARIOS],
    output:
        report(
            multiext(f"{OUT}/fig3_joint_vs_marginal", ".pdf", ".png"),
            caption="../report/fig3.rst",
            category="Figures",
        ),
    log:
        "results/shared/logs/figure_joint_vs_marginal.log",
    params:
        scenarios=[SCENARIOS[n] for n in TABLE_II_SCENARIOS],
        joint={n: f"results/{n}/joint_map/joint_map.parquet" for n in TABLE_II_SCENARIOS},
        marginal={n: f"results/{n}/gather_nuts/marginal_map.parquet" for n in TABLE_II_SCENARIOS},
    localrule: True
    conda:
        "../../envs/ssmobs.yaml"
    script:
        "../scripts/figure_joint_vs_marginal.py"


rule figure_observability:
    """|K^max|/K and |K^Stan|/K across all scenarios, ours beside the paper's."""
    input:
        f"{OUT}/section4_summary.csv",
    output:
        report(
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


rule convergence_sensitivity:
    """|K^Stan| of every scenario under R-hat 1.01 / 1.05 and tree depth warned / counted."""
    input:
        [f"results/{n}/gather_nuts/marginal_map.parquet" for n in STAN_SCENARIOS],
    output:
        report(
            multiext(f"{OUT}/table_convergence_sensitivity", ".csv", ".md", ".tex"),
            caption="../report/convergence_sensitivity.rst",
            category="Tables",
        ),
    log:
        "results/shared/logs/convergence_sensitivity.log",
    params:
        tables={n: f"results/{n}/gather_nuts/marginal_map.parquet" for n in STAN_SCENARIOS},
        convergence=config["convergence"],
    localrule: True
    conda:
        "../../envs/ssmobs.yaml"
    script:
        "../scripts/convergence_sensitivity.py"
