# The variant x row table of Section IV (issue 20): read from the committed studies that
# config/tables/stan_variants_by_row.yaml names, never from results/; made on request
# (`make variant-table`), not by `all`.

from ssmobs.reports.stan_variants import read_spec, spec_inputs, table_key

VARIANT_TABLE_SPEC = "config/tables/stan_variants_by_row.yaml"
VARIANT_TABLE = read_spec(VARIANT_TABLE_SPEC)
VARIANT_TABLE_INPUTS = spec_inputs(VARIANT_TABLE)
# its stamp: the content key of the spec, the committed files, the code that reads them and
# the code of every model the committed configs name (their propriety notes), so that an edit of any of them remakes the table whatever the file times say
VARIANT_TABLE_STAMP = "results/outputs/stan_variant_table.key"
if all(Path(p).is_file() for p in VARIANT_TABLE_INPUTS):
    STAMPS_ON_REQUEST[VARIANT_TABLE_STAMP] = table_key([VARIANT_TABLE_SPEC, *VARIANT_TABLE_INPUTS])


rule stan_variant_table:
    """|K^Stan|/K per Stan set-up and row, beside each row's own set-up and the paper's."""
    input:
        spec=VARIANT_TABLE_SPEC,
        committed=VARIANT_TABLE_INPUTS,
    output:
        csv=f"{VARIANT_TABLE['output']}.csv",
        md=f"{VARIANT_TABLE['output']}.md",
        stamp=VARIANT_TABLE_STAMP,
    log:
        "results/logs/stan_variant_table.log",
    localrule: True
    conda:
        "../../envs/ssmobs.yaml"
    params:
        key=lambda wc, output: STAMPS_ON_REQUEST[output.stamp],
    script:
        "../scripts/stan_variant_table.py"
