# Source data (params.yaml source.dataset, metraw.study.sources): the embedded synthetic drone scenes, a team's own
# calibrated camera raws with car masks, or processed photos with boxes or masks; raw array stored with the
# noise-preserving codec (params.yaml codec), then a calibration check of the stored profiles.

if config["source"]["dataset"] == "synthetic":

    rule source_store:
        input:
            params_file=ancient(PARAMS_FILE),  # the effective params (Snakefile); params: track its values
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
            mem_mb=3000,  # measured peak RSS with head room (docs/workflow.md, "Resources per rule")
            runtime=60,  # minutes, a generous bound on the measured wall time
        log:
            "logs/source_store.log",
        shell:
            "metraw scenes --n {params.synthetic[n_scenes]} --seed {params.synthetic[seed]}"
            " --size {params.synthetic[size_px]} --camera {input.params_file} --out {output} --workers {threads}"
            " --codec-step {params.codec[step]} --codec-seed {params.codec[seed]} 2> {log}"

else:

    rule source_check:
        """One pass over the raws or photos folder before anything runs (metraw check-folder, metraw.study.folder):
        every image has its labels, of its size and a valid range, one sensor, cars in the test split; every problem
        one line, the calibration and the ingest wait for it (results/source/folder_check.json: the summary)."""
        input:
            images=SOURCE_FILES["images"],
            params_file=ancient(PARAMS_FILE),  # the effective params (Snakefile); params: track its values
        output:
            SOURCE_CHECK,
        params:
            args=check_folder_arguments(config),
        priority: 1000  # every job waits for it
        resources:
            mem_mb=1000,
            runtime=10,  # minutes
        log:
            "logs/source_check.log",
        shell:
            # the problems on the terminal too (tee): they are what the user must fix before anything runs
            "metraw check-folder {params.args} --out {output} 2>&1 | tee {log}"


if config["source"]["dataset"] == "raws":
    # A team's own camera raws (metraw.study.sources): the camera calibrated first (photon transfer from flats and
    # darks, a given profile, or the single-frame fit of the raws), then the raws ingested with that camera's
    # noise model and geometry and their car masks.
    RAWS = config["source"]["raws"]
    RAWS_CALIBRATION = RAWS.get("calibration") or {}
    RAWS_METHOD = calibration_method(RAWS)

    rule source_camera:
        """The source camera's calibrated profile (results/source/camera.json: params' camera with the measured
        gain, read noise and black level and their uncertainties) and the whole fit (camera_calibration.json)."""
        input:
            check=SOURCE_CHECK,  # the folder checked first
            images=SOURCE_FILES["images"],
            flats=SOURCE_FILES.get("flats", []),
            darks=SOURCE_FILES.get("darks", []),
            profile=SOURCE_FILES.get("profile", []),
            params_file=ancient(PARAMS_FILE),  # the effective params (Snakefile); params: track its values
        output:
            profile=SOURCE_CAMERA,
            report="results/source/camera_calibration.json",
        params:
            camera=config["source"]["camera"],
            method=RAWS_METHOD,
            gsd=f" --gsd-m {RAWS['gsd_m']}" if RAWS.get("gsd_m") else "",
            command=_calibrate_command,
        resources:
            mem_mb=2000,
            runtime=20,  # minutes
        log:
            "logs/source_camera.log",
        shell:
            "metraw calibrate {params.command} --camera {input.params_file} --out {output.profile}"
            " --report {output.report}{params.gsd} > {log} 2>&1"

    rule source_store:
        input:
            check=SOURCE_CHECK,
            images=SOURCE_FILES["images"],
            camera=SOURCE_CAMERA,
        output:
            directory(SOURCE_STORE),
        params:
            path=RAWS["path"],
            labels=RAWS.get("labels", "mask"),
            classes=car_class_arguments(RAWS),
            codec=config["codec"],
        priority: 1000  # every job waits for it
        resources:
            mem_mb=2000,
            runtime=20,  # minutes
        log:
            "logs/source_store.log",
        shell:
            "metraw ingest {params.path} --labels {params.labels}{params.classes} --camera {input.camera} --out {output}"
            " --codec-step {params.codec[step]} --codec-seed {params.codec[seed]} 2> {log}"

elif config["source"]["dataset"] == "photos":

    rule source_store:
        input:
            SOURCE_FILES["images"],
            check=SOURCE_CHECK,
            params_file=ancient(PARAMS_FILE),  # the effective params (Snakefile); params: track its values
        output:
            directory(SOURCE_STORE),
        params:
            photos=config["source"]["photos"],
            labels=config["source"]["photos"].get("labels", "yolo"),
            classes=car_class_arguments(config["source"]["photos"]),
            camera=config["source"]["camera"],
            codec=config["codec"],
        priority: 1000  # every job waits for it: before the sim-to-real emulations (priority <= ~600), as pretrain_scenes
        resources:
            mem_mb=2000,  # as real_store (the same ingest of photos)
            runtime=20,  # minutes
        log:
            "logs/source_store.log",
        shell:
            "metraw ingest {params.photos[path]} --labels {params.labels}{params.classes} --camera {input.params_file}"
            " --gsd-m {params.photos[gsd_m]} --white-fraction {params.photos[white_fraction]}"
            " --seed {params.photos[seed]} --out {output}"
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
        mem_mb=1500,  # measured peak RSS with head room (docs/workflow.md, "Resources per rule")
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
        mem_mb=1000,  # measured peak RSS with head room (docs/workflow.md, "Resources per rule")
        runtime=10,  # minutes, a generous bound on the measured wall time
    log:
        "logs/calibrate_source.log",
    script:
        "../scripts/calibrate_store.py"
