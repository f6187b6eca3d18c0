# Compression per point, then the Gaussian-process aggregate: tolerances, spec, figures.


rule compress:
    input:
        "results/points/{point}/target.zarr",
    output:
        "results/points/{point}/compression.json",
    params:
        codec=config["codec"],
    # 1: the images are coded one at a time, and the default sweep's target frames (<= ~130 rows; a frame under
    # 256 rows is one codec row tile) give the codec's threads nothing to share; with 2 declared threads every
    # compress job waited for both cores to be free (default run of 2026-11-26: 15 of the 20 ran in its last 14 %)
    threads: 1
    resources:
        mem_mb=1000,  # measured peak RSS with head room (docs/workflow.md, "Resources per rule")
        runtime=20,  # minutes, a generous bound on the measured wall time
    log:
        "logs/compress/{point}.log",
    shell:
        "metraw compress {input} --out {output} --step {params.codec[step]} --seed {params.codec[seed]}"
        " --overwrite 2> {log}"


rule aggregate:
    input:
        metrics=expand("results/points/{point}/metrics.json", point=POINTS),
        # with screening (target.adaptive.screen) the screened points' too: the ratio needs no training
        compression=expand("results/points/{point}/compression.json", point=dict.fromkeys(POINTS + SCREEN_POINTS)),
        stores=expand("results/points/{point}/target.zarr", point=POINTS),
        screens=expand(SCREEN_METRICS, point=SCREEN_POINTS),  # the box model's scores (target.adaptive.screen)
        # sim-to-real benchmark (when on): each point's model on its emulated real images, the source model's pair
        real=expand(REAL_POINT_METRICS, point=POINTS) if SIM_TO_REAL else [],
        source_real=[SOURCE_REAL_METRICS, "results/source/metrics.json"] if SIM_TO_REAL else [],
        params_file=ancient(PARAMS_FILE),  # the effective params (Snakefile); params: track its values
    output:
        spec=report("results/spec.yaml", caption="../report/spec.rst", category="Specification"),
        table=report("results/aggregate.json", caption="../report/aggregate.rst", category="Specification"),
        figures=report(directory("results/figures"), patterns=["{name}.png"], caption="../report/figures.rst",
                       category="Figures"),
        plots=directory("results/plots"),
    params:
        points=POINTS,
        spec=config["spec"],
        # metraw's own code (metraw.provenance.code_digest): part of the cache key below, so a changed package
        # recomputes the aggregate instead of taking the old code's outputs from the cache
        code=METRAW_CODE,
        # extra aggregate arguments of the sim-to-real benchmark (a function: a params string would be formatted
        # with the job's wildcards, and {point} is the aggregate's own pattern)
        screen=lambda wildcards: f" --screen-pattern '{SCREEN_METRICS}'" if SCREEN_POINTS else "",
        real=lambda wildcards: (f" --real-metrics-pattern '{REAL_POINT_METRICS}' --source-real-metrics "
                                f"{SOURCE_REAL_METRICS} --source-metrics results/source/metrics.json"
                                ) if SIM_TO_REAL else "",
    # Between-workflow output cache (active with --cache, which profiles/default sets; location from the Snakefile):
    # keyed by Snakemake's provenance hash (this command, these params, and the same hash of every upstream job,
    # down to the checksums of files no rule makes). A job whose key is in the cache is not run: its outputs are
    # symlinked from the cache, so reverting a sweep value restores the old aggregate instead of recomputing it.
    # The key covers metraw's own code through params.code (metraw.provenance).
    cache: True
    resources:
        mem_mb=1500,  # measured peak RSS with head room (docs/workflow.md, "Resources per rule")
        runtime=20,  # minutes, a generous bound on the measured wall time
    log:
        "logs/aggregate.log",
    shell:
        "metraw aggregate --params {input.params_file} --results results --out results"
        " --metrics-pattern 'results/points/{{point}}/metrics.json'"
        " --compression-pattern 'results/points/{{point}}/compression.json'"
        " --stores-pattern 'results/points/{{point}}/target.zarr'{params.screen}{params.real} 2> {log}"
