# Stage 4: the paper's tables in paper_figures/ (ours beside the paper's values); figures: figures.smk.

# the paper's tables, and the convergence tables below, where the config asks for them
# (PATHS.paper_outputs: it names a scenario of the paper or sets paper_outputs)
if PATHS.paper_outputs:
    register_stamp(
        "paper_tables",
        [
            *PATHS.paper_tables_inputs()["joint"],
            *PATHS.paper_tables_inputs()["marginal"],
            *PATHS.paper_tables_inputs()["exact"],
            "config/paper_values.yaml",
        ],
        PATHS.paper_tables_params(),
    )


rule paper_tables:
    """Tables II, III and the Section IV summary as CSV, Markdown and LaTeX."""
    input:
        **PATHS.paper_tables_inputs(),
    output:
        table2=report(
            multiext(f"{OUT}/table2_joint_vs_marginal", ".csv", ".md", ".tex"),
            caption="../report/table2.rst",
            category="Tables",
        ),
        table3=report(
            multiext(f"{OUT}/table3_coverage", ".csv", ".md", ".tex"),
            caption="../report/table3.rst",
            category="Tables",
        ),
        section4_csv=f"{OUT}/section4_summary.csv",
        section4=report(
            multiext(f"{OUT}/section4_summary", ".md", ".tex"),
            caption="../report/section4.rst",
            category="Tables",
        ),
        stamp=PATHS.stamp("paper_tables"),
    log:
        f"results/outputs/{OUT}/logs/paper_tables.log",
    localrule: True
    conda:
        "../../envs/ssmobs.yaml"
    params:
        **PATHS.paper_tables_params(),
        key=stamp_key,
    script:
        "../scripts/paper_tables.py"


if PATHS.paper_outputs:
    register_stamp(
        "convergence_sensitivity",
        [PATHS.stan_table(n) for n in PATHS.stan_scenarios],
        {"scenarios": PATHS.stan_scenarios, "convergence": config["convergence"]},
    )


rule convergence_sensitivity:
    """|K^Stan| of every scenario under R-hat 1.01 / 1.05 and tree depth warned / counted, and
    how the runs that did not converge failed."""
    input:
        tables=[PATHS.stan_table(n) for n in PATHS.stan_scenarios],
    output:
        table=report(
            multiext(f"{OUT}/table_convergence_sensitivity", ".csv", ".md", ".tex"),
            caption="../report/convergence_sensitivity.rst",
            category="Tables",
        ),
        failures=multiext(f"{OUT}/table_convergence_failures", ".csv", ".md", ".tex"),
        stamp=PATHS.stamp("convergence_sensitivity"),
    log:
        f"results/outputs/{OUT}/logs/convergence_sensitivity.log",
    localrule: True
    conda:
        "../../envs/ssmobs.yaml"
    params:
        scenarios=PATHS.stan_scenarios,
        convergence=config["convergence"],
        key=stamp_key,
    script:
        "../scripts/convergence_sensitivity.py"
