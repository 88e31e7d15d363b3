# Any model, including your own (docs/your-own-model.md): the model check that runs before the
# chain, and observability studies of one model over several horizons T (ours, not the paper's).


rule check_model:
    """Python model against Stan program: shapes, derivatives, log density, prior bounds."""
    input:
        module="workflow/ssmobs/models/{model}.py",
        stan="stan/{model}.stan",
    output:
        "results/shared/check_model/{model}.json",
    log:
        "results/shared/logs/check_model/{model}.log",
    conda:
        "../../envs/ssmobs.yaml"
    resources:
        mem_mb=4000,
        runtime=30,
    params:
        scenarios=lambda wc: [sc for sc in config["scenarios"] if sc["model"] == wc.model],
        stan=lambda wc: any(sc["stan"] for sc in config["scenarios"] if sc["model"] == wc.model),
    script:
        "../scripts/check_model.py"


rule observability_study:
    """|K^max|/K and |K^Stan|/K of one model over T: table and figure in paper_figures/."""
    input:
        joint=lambda wc: [
            joint_summary(sc["name"]) for sc in study_scenarios(wc.study) if sc["joint_map"]
        ],
        stan=lambda wc: [stan_summary(sc["name"]) for sc in study_scenarios(wc.study) if sc["stan"]],
        stan_tables=lambda wc: [
            f"results/{sc['name']}/gather_nuts/marginal_map.parquet"
            for sc in study_scenarios(wc.study)
            if sc["stan"]
        ],
    output:
        csv=f"{OUT}/ours_{{study}}_observability.csv",
        md=f"{OUT}/ours_{{study}}_observability.md",
        png=f"{OUT}/ours_{{study}}_observability.png",
    log:
        "results/shared/logs/observability_study/{study}.log",
    localrule: True
    conda:
        "../../envs/ssmobs.yaml"
    params:
        study=lambda wc: STUDIES[wc.study],
        scenarios=lambda wc: study_scenarios(wc.study),
        joint_names=lambda wc: [sc["name"] for sc in study_scenarios(wc.study) if sc["joint_map"]],
        stan_names=lambda wc: [sc["name"] for sc in study_scenarios(wc.study) if sc["stan"]],
        stan_settings=config["stan"],
    script:
        "../scripts/observability_study.py"
