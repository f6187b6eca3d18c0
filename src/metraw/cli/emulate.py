"""``metraw emulate``: emulate a target system's raws from a source RawStore (one output store per point)."""

from __future__ import annotations

import argparse
import time
from pathlib import Path

from metraw.cli._rawcodec import StoreCodec, add_arguments as add_codec_arguments


def register(subparsers) -> None:
    p = subparsers.add_parser("emulate", help="emulate the raws a target system (satellite) would record",
                              description="Photon-exact / expected-value emulation of a target system from a "
                              "source RawStore (docs/emulation.md). The target is target.nominal of the "
                              "parameter file, updated by --point, or the parameter point named by --at-point.")
    p.add_argument("source", help="source RawStore (zarr)")
    p.add_argument("output", help="output RawStore (zarr), written atomically")
    p.add_argument("--point", default="", help="target overrides name=value,... (any TargetSystem field; "
                   "tuples with ':', e.g. frame_offset_m=10:-5), e.g. focal_length_m=1.644,diameter_m=0.2")
    p.add_argument("--at-point", default=None, metavar="NAME",
                   help="the target of the parameter file's point NAME (metraw.study.points.target_params: the nominal "
                   "with the point's overrides, merged once), e.g. diameter_m-0.5; what the workflow passes")
    p.add_argument("--params", default="params.yaml", help="parameter file with target.nominal (default params.yaml)")
    p.add_argument("--mode", choices=("photon", "expected", "auto"), default=None,
                   help="emulation chain (default: target.emulation.mode of the parameter file, else auto)")
    p.add_argument("--seed", type=int, default=None, help="seed (default: target.emulation.seed, else 0); "
                   "image i uses seed (seed, i)")
    p.add_argument("--edge", choices=("reflect", "zero", "valid"), default="reflect", help="edge policy")
    p.add_argument("--accuracy", default="", help="Accuracy overrides name=value,... (e.g. kernel_flux_loss=1e-2)")
    p.add_argument("--images", choices=("all", "test"), default="all",
                   help="source images to emulate: all (default), or only the test split of the parameter file's "
                   "training section (split_seed, test_fraction): all a point needs when its models train on fresh "
                   "draws of the source (`metraw train --source`)")
    p.add_argument("--limit", type=int, default=None, help="emulate only the first N of those images")
    p.add_argument("--overwrite", action="store_true", help="replace an existing output")
    p.add_argument("--workers", type=int, default=2, help="worker processes (bytes do not depend on it; default 2)")
    add_codec_arguments(p)
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    import numpy as np

    from metraw.emulate.target import TargetSystem, parse_point
    from metraw.errors import MetrawError
    from metraw.io.store import RawStore
    from metraw.physics.accuracy import Accuracy
    from metraw.progress import progress_bar
    from metraw.study.points import load_params

    codec = StoreCodec(args)
    params = load_params(args.params)
    emu = dict((params.get("target") or {}).get("emulation") or {})
    mode = args.mode or emu.get("mode", "auto")
    seed = args.seed if args.seed is not None else int(emu.get("seed", 0))
    if seed < 0:
        raise MetrawError(f"--seed must be >= 0, got {seed}")
    if args.workers < 1:
        raise MetrawError(f"--workers must be >= 1, got {args.workers}")
    if args.limit is not None and args.limit < 1:
        raise MetrawError(f"--limit must be >= 1, got {args.limit}")
    if args.at_point is not None and args.point:
        raise MetrawError("give --point (overrides) or --at-point (a point of the parameter file), not both")
    if args.at_point is not None:
        from metraw.study.points import target_params

        target = TargetSystem.from_dict(target_params(params, args.at_point))
    else:
        target = TargetSystem.from_params(params, parse_point(args.point))
    acc_over = {}
    for item in filter(None, (s.strip() for s in args.accuracy.split(","))):
        if "=" not in item:
            raise MetrawError(f"--accuracy item {item!r} is not name=value")
        k, v = item.split("=", 1)
        acc_over[k.strip()] = v
    try:
        accuracy = Accuracy.from_dict(acc_over)
    except (TypeError, ValueError) as exc:
        raise MetrawError(f"--accuracy: {exc}") from None
    if not Path(args.source).exists():
        raise MetrawError(f"source store {args.source} does not exist")
    source = RawStore.open(args.source)
    if len(source) < 1:
        raise MetrawError(f"source store {args.source} holds no images")
    images = args.images
    indices = _source_images(len(source), images, args.params)[:args.limit]
    n = len(indices)
    t0 = time.perf_counter()
    mean_e = []
    with RawStore.create(args.output, overwrite=args.overwrite, **codec.create_kwargs()) as out:
        # a test-split store records which source images it holds (metraw.segment.data.source_indices); a store of
        # all images (or their first --limit) is image i from source image i, a data set of its own
        subset = {"source_images": len(source), "source_indices": [int(i) for i in indices]} if images == "test" else {}
        out.set_attrs(generator="metraw.emulate", source=source.origin, target=target.to_dict(), mode=mode,
                      seed=seed, edge=args.edge, accuracy=accuracy.to_dict(), images=images, **subset,
                      **codec.attrs())
        job = _Job(str(args.source), target, mode, seed, accuracy, args.edge)
        for img in progress_bar(_emulated(job, indices, args.workers), total=n, desc="emulate"):
            mean_e.append(img.meta["emulation"]["mean_signal_e"])
            out.append(codec.mark(img))
            ratio = img.meta["emulation"]["gsd_ratio"]
    dt = time.perf_counter() - t0
    print(f"metraw emulate: {n} images ({images}) -> {args.output} in {dt:.1f} s ({dt / n:.3f} s/image); GSD ratio {ratio:.3g}, "
          f"mean signal {np.mean(mean_e):.3g} e- per target pixel, mode {mode}, {args.workers} workers")
    return 0


def _source_images(n_source: int, images: str, params_path) -> list[int]:
    """Indices of the source images to emulate: all, or the test split of ``params_path``'s training section."""
    if images == "all":
        return list(range(n_source))
    from metraw.segment.data import split_indices
    from metraw.segment.config import TrainConfig, load_config

    try:
        config = load_config(params_path)
    except MetrawError:  # a parameter file without training profiles: the training defaults
        config = TrainConfig()
    return split_indices(n_source, config.test_fraction, config.split_seed)[1].tolist()


class _Job:
    """Emulation of image i of a source store (picklable; each process opens the store once)."""

    def __init__(self, source: str, target, mode: str, seed: int, accuracy, edge: str):
        self.source, self.target, self.mode, self.seed, self.accuracy, self.edge = source, target, mode, seed, accuracy, edge
        self._store = None

    def __getstate__(self):
        return {**self.__dict__, "_store": None}

    def __call__(self, i: int):
        import numpy as np

        from metraw.emulate.emulator import emulate
        from metraw.io.store import RawStore

        if self._store is None:
            self._store = RawStore.open(self.source)
        rng = np.random.Generator(np.random.PCG64([self.seed, i]))  # image i: seed (seed, i), any worker count
        img = emulate(self._store[i], self.target, mode=self.mode, seed=rng, accuracy=self.accuracy, edge=self.edge)
        img.provenance[-1]["params"]["seed"] = [self.seed, i]
        return img


def _emulated(job: _Job, indices: list[int], workers: int):
    """Source images ``indices`` emulated, in order; ``workers`` > 1 emulates them in worker processes."""
    from metraw import codec
    from metraw.parallel import ordered_map

    # each process decodes its source images on one codec thread: --workers is the cores used
    with codec.threads(1):
        yield from ordered_map(job, indices, workers, chunksize=4)
