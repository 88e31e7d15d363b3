# Stage 4: the paper's tables in paper_figures/ (ours beside the paper's values); figures: figures.smk.

# the paper's tables and the convergence tables below are made where the config asks for
# them (it names a scenario of the paper or sets paper_outputs); the files each reads, what it
# reads beside them and its stamp's key: PATHS.stamped_outputs


rule paper_tables:
    """Tables II, III and the Section IV summary as CSV, Markdown and LaTeX."""
    input:
        unpack(stamped_files("paper_tables")),
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
        inputs=stamped_inputs,
        key=stamp_key,
    script:
        "../scripts/paper_tables.py"


rule convergence_sensitivity:
    """|K^Stan| of every scenario under R-hat 1.01 / 1.05 and tree depth warned / counted, and
    how the runs that did not converge failed."""
    input:
        unpack(stamped_files("convergence_sensitivity")),
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
        inputs=stamped_inputs,
        key=stamp_key,
    script:
        "../scripts/convergence_sensitivity.py"
