# Stage 4: the paper's tables in paper_figures/ (ours beside the paper's values); figures: figures.smk.

PAPER_TABLES_INPUTS = {
    "joint": [PATHS.joint_summary(n) for n in JOINT_SCENARIOS],
    "marginal": [PATHS.stan_summary(n) for n in STAN_SCENARIOS],
    "exact": [PATHS.exact_summary(n) for n in EXACT_SCENARIOS],
    "paper_values": "config/paper_values.yaml",
}
PAPER_TABLES_PARAMS = {
    "scenarios": config["scenarios"],
    "tables_2_3": TABLE_II_SCENARIOS,
    "joint_names": JOINT_SCENARIOS,
    "marginal_names": STAN_SCENARIOS,
    "exact_names": EXACT_SCENARIOS,
}
# the paper's tables, and the convergence tables below, where the config asks for them
# (PAPER_OUTPUTS: it names a scenario of the paper or sets paper_outputs)
if PAPER_OUTPUTS:
    register_stamp(
        "paper_tables",
        [
            *PAPER_TABLES_INPUTS["joint"],
            *PAPER_TABLES_INPUTS["marginal"],
            *PAPER_TABLES_INPUTS["exact"],
            "config/paper_values.yaml",
        ],
        PAPER_TABLES_PARAMS,
    )


rule paper_tables:
    """Tables II, III and the Section IV summary as CSV, Markdown and LaTeX."""
    input:
        **PAPER_TABLES_INPUTS,
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
        **PAPER_TABLES_PARAMS,
        key=stamp_key,
    script:
        "../scripts/paper_tables.py"


SENSITIVITY_INPUTS = [PATHS.stan_table(n) for n in STAN_SCENARIOS]
if PAPER_OUTPUTS:
    register_stamp(
        "convergence_sensitivity",
        SENSITIVITY_INPUTS,
        {"scenarios": STAN_SCENARIOS, "convergence": config["convergence"]},
    )


rule convergence_sensitivity:
    """|K^Stan| of every scenario under R-hat 1.01 / 1.05 and tree depth warned / counted, and
    how the runs that did not converge failed."""
    input:
        tables=SENSITIVITY_INPUTS,
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
        scenarios=STAN_SCENARIOS,
        convergence=config["convergence"],
        key=stamp_key,
    script:
        "../scripts/convergence_sensitivity.py"
