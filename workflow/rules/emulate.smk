# Emulate the target (satellite) raws of every parameter point from the source store; the raw
# array is stored with the noise-preserving codec at params.yaml codec.step.


def point_overrides(wildcards):
    """All target fields of the point as 'name=value' pairs for `metraw emulate --point`."""
    target = point_target(wildcards)
    return ",".join(f"{k}={v}" for k, v in target.items() if not isinstance(v, (dict, list)))


def emulation_priority(wildcards):
    """Light collected relative to nominal, D^2 (1 - eps^2) t (x100): the emulation's cost grows with it
    (the photon-exact chain costs per photon), so the brightest points start first and the two cores
    finish together (longest job first; the D = 0.5 m point alone takes ~4x a nominal one)."""
    t, n = point_target(wildcards), config["target"]["nominal"]

    def light(v):
        return v["diameter_m"] ** 2 * (1 - v.get("obscuration_ratio", 0.0) ** 2) * v["exposure_s"]

    return int(round(100 * light(t) / light(n)))


rule emulate:
    input:
        source=SOURCE_STORE,
        decoded=ancient(SOURCE_DECODED),  # what the command reads (common.smk)
    output:
        directory("results/points/{point}/target.zarr"),
    params:
        target=point_target,
        point=point_overrides,
        emulation=config["target"].get("emulation", {}),
        images=config["target"].get("emulation", {}).get("images", "all"),
        # the test split (images: test) is the training section's; a change to it re-emulates
        split={k: config["training"][k] for k in ("split_seed", "test_fraction") if k in config["training"]},
        codec=config["codec"],
    threads: 1  # one process per point; the points share the cores (see emulation_priority)
    priority: emulation_priority
    resources:
        mem_mb=2000,  # measured peak RSS with head room (README, SLURM: resources table)
        runtime=60,  # minutes, a generous bound on the measured wall time
    log:
        "logs/emulate/{point}.log",
    shell:
        "metraw emulate {input.decoded} {output} --params {PARAMS_FILE} --point '{params.point}'"
        " --mode {params.emulation[mode]} --seed {params.emulation[seed]} --images {params.images} --workers {threads}"
        " --codec-step {params.codec[step]} --codec-seed {params.codec[seed]} 2> {log}"
