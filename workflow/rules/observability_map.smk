# Observability maps (issue 21, ours): one job per map computes its cells, each cached on its
# own under its key in results/observability_map/cells/ (an extended grid computes only the
# new cells); a second one writes the map's table and figure.


rule observability_map_cells:
    """Every cell of one map: design set, joint MAP and (models linear in the states) exact
    marginal; each cell cached as it finishes."""
    output:
        table="results/observability_map/{map}/{key}/cells.parquet",
    log:
        "results/observability_map/{map}/{key}/cells.log",
    conda:
        "../../envs/ssmobs.yaml"
    threads: 1
    resources:
        mem_mb=4000,
        runtime=120,
    params:
        # what the job reads: the object its key is made of (ssmobs.config.stage_inputs)
        inputs=lambda wc: expect_key("map", wc.map, wc.key)["inputs"],
    script:
        "../scripts/observability_map_cells.py"


# the map's table and figure: the files it reads, what it reads beside them and its stamp's
# key: PATHS.stamped_outputs (ssmobs.config.stage_inputs.stamped)


rule observability_map:
    """Where in (true parameter, T) one model is observable, and how well: table and figure."""
    input:
        unpack(stamped_files("map_{map}")),
    output:
        csv=f"{OUT}/map_{{map}}.csv",
        md=f"{OUT}/map_{{map}}.md",
        png=report(
            f"{OUT}/map_{{map}}.png",
            caption="../report/observability_map.rst",
            category="Observability maps",
        ),
        pdf=f"{OUT}/map_{{map}}.pdf",
        stamp=PATHS.stamp("map_{map}"),
    log:
        f"results/outputs/{OUT}/logs/observability_map/{{map}}.log",
    localrule: True
    conda:
        "../../envs/ssmobs.yaml"
    params:
        inputs=stamped_inputs,
        key=stamp_key,
    script:
        "../scripts/observability_map.py"
