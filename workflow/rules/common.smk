import re

# Shared definitions: the parameter points come from params.yaml via metraw.study.points,
# never from a glob of existing outputs.

from snakemake.exceptions import WorkflowError

from metraw.spec.screening import DEFAULT_SCREEN
from metraw.study.points import parameter_points, screen_points, target_params
from metraw.provenance import code_digest
from metraw.study.sources import calibration_method, car_class_arguments, check_folder_arguments
from metraw.study.pretraining import (draws_extra_scenes, fine_tuned_points, point_patterns, pretrain_settings,
                                      pretrained_patterns)

POINTS = list(parameter_points(config))
# the adaptive sweep's screening (target.adaptive.screen): the points the box model alone is scored on (rule screen)
SCREEN_POINTS = list(screen_points(config))
SCREEN_METRICS = DEFAULT_SCREEN.format(results="results", point="{point}")  # metraw aggregate's default
SOURCE_CAMERA = "results/source/camera.json"  # the raws source's calibrated camera (rule source_camera)
SOURCE_CHECK = "results/source/folder_check.json"  # a raws or photos folder checked (rule source_check)
METRAW_CODE = code_digest()  # the aggregate's cache key covers metraw's code (workflow/rules/aggregate.smk)
SOURCE_STORE = "data/source.zarr"
# The stores many jobs read (the source: every emulation, training and the pretraining; the real photos: every
# point's emulate_real) are read from a decoded working copy, the raw array uncompressed (the decode_store rule: ~12
# instead of ~42 ms of CPU per 1 MP image, at 4x the disk). A reader lists both: the store, whose change reruns it,
# and the copy, what its command reads, as ancient (a copy a DVC stage wrote after the readers' outputs reruns
# none of them). The copy is an ordinary intermediate output: deleting it reruns its readers, as deleting a store
# would. (Not temp(): Snakemake would re-create a deleted temporary copy for one new point and then rerun every
# reader, since ancient spares only readers of an existing file.)
SOURCE_DECODED = "data/source.decoded.zarr"

# Pretraining across the box (params.yaml training.pretrain; workflow/rules/segment.smk): one pretraining per CFA
# pattern among the points (one network per replicate each); every point fine-tunes its pattern's.
PRETRAIN = pretrain_settings(config)
PRETRAINED_MODEL = "results/pretrained/{cfa_pattern}/model"
PRETRAINED_PATTERNS = pretrained_patterns(config)
PRETRAIN_SCENES = "data/pretrain_scenes.zarr"
PRETRAIN_EXTRA = [PRETRAIN_SCENES] if draws_extra_scenes(config) else []
PRETRAINED_POINTS = set(fine_tuned_points(config))
POINT_PATTERNS = point_patterns(config)

# Sim-to-real benchmark (workflow/rules/sim_to_real.smk, when SIM_TO_REAL): the real photos as a store, emulated
# per point, scored by each point's model; the drone-resolution model scored on the un-emulated store.
REAL_STORE = "data/real.zarr"
REAL_DECODED = "data/real.decoded.zarr"
REAL_POINT_METRICS = "results/points/{point}/real_metrics.json"
SOURCE_REAL_METRICS = "results/source/real_metrics.json"
SIM_TO_REAL_METRICS = (expand(REAL_POINT_METRICS, point=POINTS) + [SOURCE_REAL_METRICS]) if SIM_TO_REAL else []


def point_target(wildcards):
    """Full target parameters of a point (tracked by Snakemake as a rule param)."""
    return target_params(config, wildcards.point)


def _check_dvc_points(check):
    """Fail in one line when a DVC stage stands for points that params.yaml does not give."""
    known = set(POINTS)
    if "dvc_point" in check and check["dvc_point"] not in known:
        raise WorkflowError(
            f"DVC stage for point {check['dvc_point']!r}, which params.yaml does not give (a sweep value equal to "
            f"the nominal one is the nominal point); points: {', '.join(POINTS)}")
    if "dvc_points" in check:
        listed = check["dvc_points"].split(",")
        if sorted(listed) != sorted(known):
            raise WorkflowError(
                f"dvc.yaml's aggregate stage lists points {', '.join(listed)} but params.yaml gives "
                f"{', '.join(POINTS)}: regenerate it with `python workflow/scripts/dvc_yaml.py`")


_check_dvc_points(DVC_CHECK)


# ----------------------------------------------------------------- the rules' functions


# rule emulate
def emulation_priority(wildcards):
    """Light collected relative to nominal, D^2 (1 - eps^2) t (x100): the emulation's cost grows with it
    (the photon-exact chain costs per photon), so the brightest points start first and the two cores
    finish together (longest job first; the D = 0.5 m point alone takes ~4x a nominal one)."""
    t, n = point_target(wildcards), config["target"]["nominal"]

    def light(v):
        return v["diameter_m"] ** 2 * (1 - v.get("obscuration_ratio", 0.0) ** 2) * v["exposure_s"]

    return int(round(100 * light(t) / light(n)))


# rules train, pretrain, evaluate
def train_inputs(wildcards):
    """The point's store and the source (and its decoded copy); the pretrained model when the point fine-tunes it."""
    inputs = {"store": f"results/points/{wildcards.point}/target.zarr", "source": SOURCE_STORE,
              "source_decoded": ancient(SOURCE_DECODED)}  # the copy is what the command reads (common.smk)
    if wildcards.point in PRETRAINED_POINTS:
        inputs["init"] = PRETRAINED_MODEL.format(cfa_pattern=POINT_PATTERNS[wildcards.point])
    return inputs


def finetune_args(wildcards, input):
    """`metraw train`'s fine-tuning options for a point that starts from the pretrained networks (else none)."""
    if "init" not in input.keys():
        return ""
    rate = PRETRAIN["finetune_learning_rate"]
    return f"--init {input.init} --epochs {PRETRAIN['finetune_epochs']}" + (f" --learning-rate {rate}" if rate else "")


def profile_threads(name):
    """Torch threads of training profile ``name`` (its `threads`, else TrainConfig's default), at most the cores:
    what its training uses, and its evaluation (`metraw evaluate` runs the model's recorded threads)."""
    from metraw.segment.config import TrainConfig

    return min(workflow.cores, int(config["training"]["profiles"][name].get("threads", TrainConfig.threads)))


# the drone-resolution reference's training profile (train_source's --profile and its jobs' threads)
SOURCE_PROFILE = config["training"].get("source_profile", config["training"]["profile"])


def source_model_threads(wildcards):
    """The drone-resolution reference's profile threads (train_source, evaluate_source[_real])."""
    return profile_threads(SOURCE_PROFILE)


def point_model_threads(wildcards):
    """The points' profile threads (evaluate, evaluate_real: the models' recorded torch threads)."""
    return profile_threads(config["training"]["profile"])


def pretrain_priority(wildcards):
    """The nominal's pattern: 1000, every fine-tuned point but a few waits for it (it runs before the emulations,
    priority <= ~600, the emulate rule). Another pattern's (mono): 20, after the points' emulations (>= 25), which
    the nominal's fine-tunings need sooner, and before the jobs of priority 0."""
    return 1000 if wildcards.cfa_pattern == PRETRAINED_PATTERNS[0] else 20


# rule source_camera (a raws source)
def _calibrate_command(wildcards, input):
    """The `metraw calibrate` arguments of the source's calibration method (metraw.study.sources)."""
    if RAWS_METHOD == "photon_transfer":
        return (f"--flats {RAWS_CALIBRATION['flats']} --darks {RAWS_CALIBRATION['darks']}"
                f" --frames-per-level {RAWS_CALIBRATION.get('frames_per_level', 2)}")
    if RAWS_METHOD == "profile":
        return f"--profile {input.profile[0]}"
    return RAWS["path"]  # the single-frame fit of the raws themselves
