# Emulate the target (satellite) raws of every parameter point from the source store; the raw
# array is stored with the noise-preserving codec at params.yaml codec.step.


rule emulate:
    input:
        source=SOURCE_STORE,
        decoded=ancient(SOURCE_DECODED),  # what the command reads (common.smk)
        params_file=ancient(PARAMS_FILE),  # the effective params (Snakefile); params: track its values
    output:
        directory("results/points/{point}/target.zarr"),
    params:
        target=point_target,
        emulation=config["target"].get("emulation", {}),
        images=config["target"].get("emulation", {}).get("images", "all"),
        # the test split (images: test) is the training section's; a change to it re-emulates
        split={k: config["training"][k] for k in ("split_seed", "test_fraction") if k in config["training"]},
        codec=config["codec"],
    threads: 1  # one process per point; the points share the cores (see emulation_priority)
    priority: emulation_priority
    resources:
        mem_mb=2000,  # measured peak RSS with head room (docs/workflow.md, "Resources per rule")
        runtime=60,  # minutes, a generous bound on the measured wall time
    log:
        "logs/emulate/{point}.log",
    shell:
        "metraw emulate {input.decoded} {output} --params {input.params_file} --at-point {wildcards.point}"
        " --mode {params.emulation[mode]} --seed {params.emulation[seed]} --images {params.images} --workers {threads}"
        " --codec-step {params.codec[step]} --codec-seed {params.codec[seed]} 2> {log}"
