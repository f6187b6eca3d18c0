# Train the same segmenter (same architecture, hyperparameters and split) on every point,
# and on the source store itself as the drone-resolution reference. A point's models learn from fresh
# draws of the source scenes at that point (sampling phase, flip, photon noise; metraw.segment.onthefly),
# `replicates` seeds each; its store's test split is the fixed test set. The drone-resolution reference
# trains one model on the source store's images (it is no point of the sweep).


rule train:
    input:
        store="results/points/{point}/target.zarr",
        source=SOURCE_STORE,
    output:
        directory("results/points/{point}/model"),
    params:
        training=config["training"],
        codec=config["codec"],
    threads: lambda wildcards: workflow.cores  # callable: --report and dry runs need no --cores
    resources:
        mem_mb=1500,  # measured peak RSS with head room (README, SLURM: resources table)
        runtime=60,  # minutes, a generous bound on the measured wall time
    log:
        "logs/train/{point}.log",
    shell:
        "metraw train {input.store} --source {input.source} --codec-step {params.codec[step]} --out {output}"
        " --params {PARAMS_FILE} 2> {log}"


rule evaluate:
    input:
        store="results/points/{point}/target.zarr",
        model="results/points/{point}/model",
    output:
        "results/points/{point}/metrics.json",
    threads: lambda wildcards: workflow.cores  # callable: --report and dry runs need no --cores
    resources:
        mem_mb=1500,  # measured peak RSS with head room (README, SLURM: resources table)
        runtime=20,  # minutes, a generous bound on the measured wall time
    log:
        "logs/evaluate/{point}.log",
    shell:
        "metraw evaluate {input.store} --model {input.model} --out {output} 2> {log}"


rule train_source:
    input:
        SOURCE_STORE,
    output:
        directory("results/source/model"),
    params:
        training=config["training"],
        profile=config["training"].get("source_profile", config["training"]["profile"]),
    threads: lambda wildcards: workflow.cores  # callable: --report and dry runs need no --cores
    resources:
        mem_mb=6000,  # measured peak RSS with head room (README, SLURM: resources table)
        runtime=120,  # minutes, a generous bound on the measured wall time
    log:
        "logs/train/source.log",
    shell:
        "metraw train {input} --out {output} --params {PARAMS_FILE} --replicates 1"
        " --profile {params.profile} 2> {log}"


rule evaluate_source:
    input:
        store=SOURCE_STORE,
        model="results/source/model",
    output:
        "results/source/metrics.json",
    threads: lambda wildcards: workflow.cores  # callable: --report and dry runs need no --cores
    resources:
        mem_mb=2000,  # measured peak RSS with head room (README, SLURM: resources table)
        runtime=20,  # minutes, a generous bound on the measured wall time
    log:
        "logs/evaluate/source.log",
    shell:
        "metraw evaluate {input.store} --model {input.model} --out {output} 2> {log}"
