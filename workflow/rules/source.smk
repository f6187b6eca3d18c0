# Source data: the embedded synthetic drone scenes or the real KIT aerial path
# (params.yaml source.dataset), raw array stored with the noise-preserving codec (params.yaml codec),
# then a calibration check of the stored profiles.

if config["source"]["dataset"] == "synthetic":

    rule source_store:
        output:
            directory(SOURCE_STORE),
        params:
            synthetic=config["source"]["synthetic"],
            camera=config["source"]["camera"],
            codec=config["codec"],
        priority: 1000  # every job waits for it: before the sim-to-real emulations (priority <= ~600), as pretrain_scenes
        # the scenes render in --workers {threads} processes (the bytes do not depend on it); 1 locally: the run
        # starts with this job and pretrain_scenes side by side, and 2 worker processes each (beside the process that
        # codes and stores) cost ~20 % more CPU per scene (pickled 7 MB scenes, 3 busy processes per job)
        threads: 1
        resources:
            mem_mb=3000,  # measured peak RSS with head room (README, SLURM: resources table)
            runtime=60,  # minutes, a generous bound on the measured wall time
        log:
            "logs/source_store.log",
        shell:
            "metraw scenes --n {params.synthetic[n_scenes]} --seed {params.synthetic[seed]}"
            " --size {params.synthetic[size_px]} --camera {PARAMS_FILE} --out {output} --workers {threads}"
            " --codec-step {params.codec[step]} --codec-seed {params.codec[seed]} 2> {log}"

else:

    rule source_store:
        output:
            directory(SOURCE_STORE),
        params:
            kit=config["source"]["kit_ais"],
            camera=config["source"]["camera"],
            codec=config["codec"],
        priority: 1000  # every job waits for it: before the sim-to-real emulations (priority <= ~600), as pretrain_scenes
        resources:
            mem_mb=2000,  # as real_store (the same ingest of the KIT photos)
            runtime=20,  # minutes
        log:
            "logs/source_store.log",
        shell:
            "metraw ingest {params.kit[path]} --labels yolo --camera {PARAMS_FILE} --gsd-m {params.kit[gsd_m]}"
            " --white-fraction {params.kit[white_fraction]} --seed {params.kit[seed]} --out {output}"
            " --codec-step {params.codec[step]} --codec-seed {params.codec[seed]} 2> {log}"


rule decode_store:
    """The decoded working copy of a store many jobs read (workflow/rules/common.smk, SOURCE_DECODED): the same
    images and attributes, the raw array uncompressed."""
    input:
        "data/{name}.zarr",
    output:
        directory("data/{name}.decoded.zarr"),
    wildcard_constraints:
        name="source|real",
    threads: 1
    priority: 2000  # its readers wait for it: right after its store
    resources:
        mem_mb=1500,  # measured peak RSS with head room (README, SLURM: resources table)
        runtime=20,  # minutes, a generous bound on the measured wall time
    log:
        "logs/decode_store/{name}.log",
    shell:
        "metraw decode {input} {output} --threads {threads} 2> {log}"


rule calibrate_source:
    """Single-frame noise calibration of source images against the profile they carry."""
    input:
        SOURCE_STORE,
    output:
        "results/source/calibration.json",
    resources:
        mem_mb=1000,  # measured peak RSS with head room (README, SLURM: resources table)
        runtime=10,  # minutes, a generous bound on the measured wall time
    log:
        "logs/calibrate_source.log",
    script:
        "../scripts/calibrate_store.py"
