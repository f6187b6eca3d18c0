# metraw workflow: source raws -> emulated target raws per parameter point -> segmenter
# training and evaluation -> compression -> Gaussian-process tolerances and figures.
# Run: snakemake --cores all        (dvc repro drives the same rules; see dvc.yaml)

from snakemake.utils import min_version, validate

min_version("9.0")

configfile: "params.yaml"

validate(config, "workflow/schemas/params.schema.yaml")


include: "workflow/rules/common.smk"
include: "workflow/rules/source.smk"
include: "workflow/rules/emulate.smk"
include: "workflow/rules/segment.smk"
include: "workflow/rules/aggregate.smk"


rule all:
    input:
        "results/source/calibration.json",
        "results/source/metrics.json",
        "results/spec.yaml",
        "results/aggregate.json",
