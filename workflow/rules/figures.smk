# Paper figures (paper_figures/).


rule figure_design_points:
    """Figure 2: five design disturbances of N(0, I_2) and the resulting (x~_1, z~_1) of model Same."""
    input:
        figure2_disturbances,
    output:
        pdf=report(f"{OUT}/fig2_design_points.pdf", caption="../report/fig2.rst",
                   category="Figures"),
        png=f"{OUT}/fig2_design_points.png",
    log:
        "results/shared/logs/figure_design_points.log",
    params:
        figure=config["figure2"],
    conda:
        "../../envs/ssmobs.yaml"
    script:
        "../scripts/figure_design_points.py"
