# Sim-to-real benchmark (issue #16; included by the Snakefile when params.yaml sim_to_real is on): the real
# photos of sim_to_real.path (KIT AIS, YOLO car boxes) ingested as approximate raws like a photos source,
# emulated through every parameter point exactly as the synthetic source (rule emulate's flags and helpers),
# and scored by that point's synthetic-trained model on all its images; the drone-resolution model is scored on
# the un-emulated store (metraw evaluate resamples it to the model's training GSD).


rule real_store:
    input:
        params_file=ancient(PARAMS_FILE),  # the effective params (Snakefile); params: track its values
    output:
        directory(REAL_STORE),
    params:
        real=config["sim_to_real"],
        camera=config["source"]["camera"],
        codec=config["codec"],
        white_fraction=config["sim_to_real"].get("white_fraction", 1.0),
        seed=config["sim_to_real"].get("seed", 0),
        labels=config["sim_to_real"].get("labels", "yolo"),
    resources:
        mem_mb=2000,  # measured peak RSS with head room (docs/workflow.md, "Resources per rule")
        runtime=20,  # minutes, a generous bound on the measured wall time
    log:
        "logs/real_store.log",
    shell:
        "metraw ingest {params.real[path]} --labels {params.labels} --camera {input.params_file} --gsd-m {params.real[gsd_m]}"
        " --white-fraction {params.white_fraction} --seed {params.seed} --out {output}"
        " --codec-step {params.codec[step]} --codec-seed {params.codec[seed]} 2> {log}"


rule emulate_real:
    input:
        real=REAL_STORE,
        decoded=ancient(REAL_DECODED),  # what the command reads (common.smk)
        params_file=ancient(PARAMS_FILE),  # the effective params (Snakefile); params: track its values
    output:
        directory("results/points/{point}/real.zarr"),
    params:
        target=point_target,
        # mode and seed only: the real store is emulated whole (target.emulation.images is the synthetic stores')
        emulation={k: v for k, v in config["target"].get("emulation", {}).items() if k != "images"},
        codec=config["codec"],
    threads: 1  # one process per point, as rule emulate
    priority: emulation_priority
    resources:
        mem_mb=1500,  # measured peak RSS with head room (docs/workflow.md, "Resources per rule")
        runtime=30,  # minutes, a generous bound on the measured wall time
    log:
        "logs/emulate_real/{point}.log",
    shell:
        "metraw emulate {input.decoded} {output} --params {input.params_file} --at-point {wildcards.point}"
        " --mode {params.emulation[mode]} --seed {params.emulation[seed]} --images all --workers {threads}"
        " --codec-step {params.codec[step]} --codec-seed {params.codec[seed]} 2> {log}"


rule evaluate_real:
    input:
        store="results/points/{point}/real.zarr",
        model="results/points/{point}/model",
    output:
        REAL_POINT_METRICS,
    threads: point_model_threads  # the model's torch threads, as rule evaluate
    resources:
        mem_mb=1500,  # measured peak RSS with head room (docs/workflow.md, "Resources per rule")
        runtime=20,  # minutes, a generous bound on the measured wall time
    log:
        "logs/evaluate_real/{point}.log",
    shell:
        "metraw evaluate {input.store} --model {input.model} --split all --out {output} 2> {log}"


rule evaluate_source_real:
    input:
        store=REAL_STORE,
        model="results/source/model",
    output:
        SOURCE_REAL_METRICS,
    threads: source_model_threads  # the model's torch threads, as rule evaluate_source
    resources:
        mem_mb=1500,  # measured peak RSS with head room (docs/workflow.md, "Resources per rule")
        runtime=20,  # minutes, a generous bound on the measured wall time
    log:
        "logs/evaluate_real/source.log",
    shell:
        "metraw evaluate {input.store} --model {input.model} --split all --out {output} 2> {log}"
