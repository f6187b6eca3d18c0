# Emulate the target (satellite) raws of every parameter point from the source store; the raw
# array is stored with the noise-preserving codec at params.yaml codec.step.


def point_overrides(wildcards):
    """All target fields of the point as 'name=value' pairs for `metraw emulate --point`."""
    target = point_target(wildcards)
    return ",".join(f"{k}={v}" for k, v in target.items() if not isinstance(v, (dict, list)))


rule emulate:
    input:
        SOURCE_STORE,
    output:
        directory("results/points/{point}/target.zarr"),
    params:
        target=point_target,
        point=point_overrides,
        emulation=config["target"].get("emulation", {}),
        codec=config["codec"],
    log:
        "logs/emulate/{point}.log",
    shell:
        "metraw emulate {input} {output} --params params.yaml --point '{params.point}'"
        " --mode {params.emulation[mode]} --seed {params.emulation[seed]}"
        " --codec-step {params.codec[step]} --codec-seed {params.codec[seed]} 2> {log}"
