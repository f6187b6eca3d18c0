# Train the same segmenter (same architecture, hyperparameters and split) on every point,
# and on the source store itself as the drone-resolution reference. A point's models learn from fresh
# draws of the source scenes at that point (sampling phase, flip, photon noise; metraw.segment.onthefly),
# `replicates` seeds each; its store's test split is the fixed test set. The drone-resolution reference
# trains one model on the source store's images (it is no point of the sweep).


if PRETRAIN["enabled"]:

    if PRETRAIN_EXTRA:

        rule pretrain_scenes:
            """Synthetic scenes for pretraining only: the source's generator and camera at the next seed, so
            that no test scene is among them. Quantised by the codec like the source and stored as the pixels it
            decodes to (--codec-decoded): `pretrain` reads them without decoding (~30 ms of CPU per scene saved
            there, ~19 ms of coding here) at ~4x the disk (~2 GB at the default 960 scenes)."""
            input:
                params_file=ancient(PARAMS_FILE),  # the effective params (Snakefile); params: track its values
            output:
                directory(PRETRAIN_SCENES),
            params:
                synthetic=config["source"]["synthetic"],
                camera=config["source"]["camera"],
                codec=config["codec"],
                n=PRETRAIN["extra_scenes"],
                seed=config["source"]["synthetic"]["seed"] + 1,
            # the start of the run's longest chain (pretrain_scenes -> pretrain -> the fine-tuned points): before the
            # sim-to-real emulations (priority <= ~600), which took the core from 15 to 679 s on 2026-11-27 without it
            priority: 1000
            threads: 1  # --workers, as source_store
            resources:
                mem_mb=3000,  # as source_store
                runtime=60,  # minutes
            log:
                "logs/pretrain_scenes.log",
            shell:
                "metraw scenes --n {params.n} --seed {params.seed}"
                " --size {params.synthetic[size_px]} --camera {input.params_file} --out {output} --workers {threads}"
                " --codec-step {params.codec[step]} --codec-seed {params.codec[seed]} --codec-decoded 2> {log}"

    rule pretrain:
        """One network per replicate on draws across training.pretrain.box (metraw.segment.pretrain) with the CFA
        pattern of the points that fine-tune it; it does not depend on the sweeps, so a changed sweep value reruns
        only its point."""
        input:
            source=SOURCE_STORE,
            decoded=ancient(SOURCE_DECODED),  # what the command reads (common.smk)
            extra=PRETRAIN_EXTRA,
            model_files=MODEL_FILES,  # a python factory's file (training.model): editing it retrains
            params_file=ancient(PARAMS_FILE),  # the effective params (Snakefile); params: track its values
        output:
            directory(PRETRAINED_MODEL),
        params:
            training=config["training"],
            codec=config["codec"],
            nominal=config["target"]["nominal"],  # the box's points are the nominal payload with one change
            pixel_scaling=config["target"].get("pixel_scaling"),
            extra=lambda wildcards, input: " ".join(f"--extra {p}" for p in input.extra),
        # all cores but one for the box's field processes (--workers), the training then takes 1 torch thread and the
        # draws' thread: on 2 cores the job starts beside others as soon as pretrain_scenes ends, instead of waiting
        # for both cores to be free at once (the default run of 2026-11-26 left it waiting from 335 to 1202 s)
        threads: lambda wildcards: max(1, workflow.cores - 1)  # callable: --report and dry runs need no --cores
        priority: pretrain_priority
        wildcard_constraints:
            cfa_pattern="|".join(re.escape(p) for p in PRETRAINED_PATTERNS),
        resources:
            mem_mb=4000,  # the box's fields: ~0.3 MB per scene and point
            runtime=60,  # minutes
        log:
            "logs/pretrain/{cfa_pattern}.log",
        shell:
            "metraw pretrain {input.decoded} {params.extra} --codec-step {params.codec[step]} --out {output}"
            " --cfa-pattern {wildcards.cfa_pattern} --params {input.params_file} --workers {threads} 2> {log}"


rule train:
    input:
        unpack(train_inputs),
        model_files=MODEL_FILES,  # a python factory's file (training.model): editing it retrains
        params_file=ancient(PARAMS_FILE),  # the effective params (Snakefile); params: track its values
    output:
        directory("results/points/{point}/model"),
    params:
        training=config["training"],
        codec=config["codec"],
        finetune=finetune_args,
    # 1 declared thread, so that two train jobs (or one beside an emulation) run at once: a job's 1 torch thread
    # (training.profiles) and its draws' prefetch thread kept ~1.6 of 2 cores busy on their own (the mono point's
    # from-scratch training ~1.2); the SLURM profile gives it 2 CPUs (set-threads), and with them 2 field processes
    threads: 1
    resources:
        mem_mb=1500,  # measured peak RSS with head room (docs/workflow.md, "Resources per rule")
        runtime=60,  # minutes, a generous bound on the measured wall time
    log:
        "logs/train/{point}.log",
    shell:
        "metraw train {input.store} --source {input.source_decoded} --codec-step {params.codec[step]} {params.finetune}"
        " --out {output} --params {input.params_file} --workers {threads} 2> {log}"


rule evaluate:
    input:
        store="results/points/{point}/target.zarr",
        model="results/points/{point}/model",
    output:
        "results/points/{point}/metrics.json",
    # the model's torch threads (1 in the default profile), so that evaluations run beside other jobs
    threads: point_model_threads
    resources:
        mem_mb=1500,  # measured peak RSS with head room (docs/workflow.md, "Resources per rule")
        runtime=20,  # minutes, a generous bound on the measured wall time
    log:
        "logs/evaluate/{point}.log",
    shell:
        "metraw evaluate {input.store} --model {input.model} --out {output} 2> {log}"


if SCREEN_POINTS:

    rule screen:
        """The adaptive sweep's screening (target.adaptive.screen; metraw.spec.screening): the pretrained box model
        alone, not fine-tuned, scored on the point's test split."""
        input:
            store="results/points/{point}/target.zarr",
            model=PRETRAINED_MODEL.format(cfa_pattern=PRETRAINED_PATTERNS[0]),  # screened points: nominal category
        output:
            SCREEN_METRICS,
        threads: point_model_threads
        resources:
            mem_mb=1500,  # as evaluate
            runtime=20,  # minutes
        log:
            "logs/screen/{point}.log",
        shell:
            "metraw evaluate {input.store} --model {input.model} --out {output} 2> {log}"


rule train_source:
    input:
        source=SOURCE_STORE,
        decoded=ancient(SOURCE_DECODED),  # what the command reads (common.smk)
        model_files=MODEL_FILES,  # a python factory's file (training.model): editing it retrains
        params_file=ancient(PARAMS_FILE),  # the effective params (Snakefile); params: track its values
    output:
        directory("results/source/model"),
    params:
        training=config["training"],
        profile=SOURCE_PROFILE,
    # the profile's torch threads (1 for the default `source` profile: the job runs beside others)
    threads: source_model_threads
    # before the emulations (priority <= ~600): the longest job no point waits for starts as soon as the source is
    # decoded, beside the pretraining, instead of last and alone (default run of 2026-11-28: it ran the final
    # 17 min on one core while the other idled; benchmarks/main_job.py)
    priority: 700
    resources:
        mem_mb=6000,  # measured peak RSS with head room (docs/workflow.md, "Resources per rule")
        runtime=120,  # minutes, a generous bound on the measured wall time
    log:
        "logs/train/source.log",
    shell:
        "metraw train {input.decoded} --out {output} --params {input.params_file} --replicates 1"
        " --profile {params.profile} 2> {log}"


rule evaluate_source:
    input:
        source=SOURCE_STORE,
        store=ancient(SOURCE_DECODED),  # what the command reads (common.smk)
        model="results/source/model",
    output:
        "results/source/metrics.json",
    threads: source_model_threads  # the model's torch threads, as rule evaluate
    resources:
        mem_mb=2000,  # measured peak RSS with head room (docs/workflow.md, "Resources per rule")
        runtime=20,  # minutes, a generous bound on the measured wall time
    log:
        "logs/evaluate/source.log",
    shell:
        "metraw evaluate {input.store} --model {input.model} --out {output} 2> {log}"
