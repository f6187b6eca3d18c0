# Compression per point, then the Gaussian-process aggregate: tolerances, spec, figures.


rule compress:
    input:
        "results/points/{point}/target.zarr",
    output:
        "results/points/{point}/compression.json",
    params:
        codec=config["codec"],
    threads: workflow.cores
    log:
        "logs/compress/{point}.log",
    shell:
        "metraw compress {input} --out {output} --step {params.codec[step]} 2> {log}"


rule aggregate:
    input:
        metrics=expand("results/points/{point}/metrics.json", point=POINTS),
        compression=expand("results/points/{point}/compression.json", point=POINTS),
    output:
        spec="results/spec.yaml",
        table="results/aggregate.json",
        figures=directory("results/figures"),
    params:
        points=POINTS,
        spec=config["spec"],
    log:
        "logs/aggregate.log",
    shell:
        "metraw aggregate --params params.yaml --results results --out results 2> {log}"
