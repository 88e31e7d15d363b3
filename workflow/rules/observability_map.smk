# Observability maps (issue 21, ours): one job per map computes its cells, each cached on its
# own under its key in results/observability_map/cells/, and writes the table and figure.

#: where the cells of every map are cached (by their own keys, shared by maps and profiles)
MAP_CELLS_DIR = "results/observability_map/cells"


def map_params(name):
    return {
        "entry": MAPS[name],
        "cells": [key for _, key in MAP_CELLS[name]],
    }


for _name in MAPS:
    register_stamp(f"map_{_name}", [], map_params(_name))


rule observability_map:
    """Where in (true parameter, T) one model is observable, and how well: every cell's
    joint MAP and exact marginal, the table and the figure."""
    output:
        csv=f"{OUT}/map_{{map}}.csv",
        md=f"{OUT}/map_{{map}}.md",
        png=report(
            f"{OUT}/map_{{map}}.png",
            caption="../report/observability_map.rst",
            category="Observability maps",
        ),
        pdf=f"{OUT}/map_{{map}}.pdf",
        stamp=stamp("map_{map}"),
    log:
        f"results/outputs/{OUT}/logs/observability_map/{{map}}.log",
    conda:
        "../../envs/ssmobs.yaml"
    threads: 1
    resources:
        mem_mb=4000,
        runtime=120,
    params:
        entry=lambda wc: MAPS[wc.map],
        cells=lambda wc: MAP_CELLS[wc.map],
        design=config["design"],
        design_dir=DESIGN_DIR,
        joint_settings=config["joint_map"],
        exact_settings=config["exact_marginal"],
        cells_dir=MAP_CELLS_DIR,
        key=stamp_key,
    script:
        "../scripts/observability_map.py"
