# Any model, including your own (docs/your-own-model.md): the model check that runs before the
# chain, and observability studies of one model over several horizons T (ours, not the paper's).


rule check_model:
    """The Python model at one scenario's true values under every prior variant: shapes,
    finite values, derivatives (before its design trajectories)."""
    input:
        # no file: the key holds the model's code (an edit that computes alike reruns nothing)
        lambda wc: keyed_input("check_model", wc.scenario, wc.key, []),
    output:
        "results/{scenario}/check_model/{key}.json",
    log:
        "results/{scenario}/check_model/{key}.log",
    conda:
        "../../envs/ssmobs.yaml"
    resources:
        mem_mb=4000,
        runtime=30,
    params:
        # what the check reads, and its key is made of (ssmobs.config.stage_inputs.ModelCheckInputs)
        inputs=lambda wc: PATHS.inputs("check_model", wc.scenario),
    script:
        "../scripts/check_model.py"


rule check_model_stan:
    """The Python model against its Stan program at one scenario's true values under every
    prior variant: parameter order, log density, prior bounds (before its NUTS runs)."""
    input:
        stan=lambda wc: keyed_input(
            "check_model_stan",
            wc.scenario,
            wc.key,
            PATHS.stan_source(PATHS.scenarios[wc.scenario].slug),
        ),
        program=lambda wc: PATHS.checked_program(PATHS.scenarios[wc.scenario].slug),
    output:
        "results/{scenario}/check_model_stan/{key}.json",
    log:
        "results/{scenario}/check_model_stan/{key}.log",
    conda:
        "../../envs/ssmobs.yaml"
    resources:
        mem_mb=4000,
        runtime=30,
    params:
        inputs=lambda wc: PATHS.inputs("check_model_stan", wc.scenario),
    script:
        "../scripts/check_model.py"


# a study's table and figure: the files it reads, what it reads beside them and its stamp's
# key: PATHS.stamped_outputs (ssmobs.config.stage_inputs.stamped)


rule observability_study:
    """|K^max|/K and |K^Stan|/K of one model over T: table and figure in paper_figures/."""
    input:
        unpack(stamped_files("observability_study_{study}")),
    output:
        csv=f"{OUT}/ours_{{study}}_observability.csv",
        md=f"{OUT}/ours_{{study}}_observability.md",
        png=f"{OUT}/ours_{{study}}_observability.png",
        stamp=PATHS.stamp("observability_study_{study}"),
    log:
        f"results/outputs/{OUT}/logs/observability_study/{{study}}.log",
    localrule: True
    conda:
        "../../envs/ssmobs.yaml"
    params:
        inputs=stamped_inputs,
        key=stamp_key,
    script:
        "../scripts/observability_study.py"
