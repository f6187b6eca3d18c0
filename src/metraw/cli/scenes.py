"""``metraw scenes``: generate the embedded synthetic source dataset (drone raws with car masks)."""

from __future__ import annotations

import argparse
import time
from pathlib import Path

from metraw.cli._rawcodec import StoreCodec, add_arguments as add_codec_arguments
from metraw.errors import MetrawError


#: The real photos of the contact sheet's last row, relative to the working directory (the repository's own).
DEFAULT_REAL_DIR = Path("data") / "real" / "kit_ais"


def register(subparsers) -> None:
    p = subparsers.add_parser("scenes", help="generate synthetic drone raw scenes with exact car masks",
                              description="Generate urban/suburban/rural drone raw scenes (Hasselblad L1D-20c at "
                              "250 m, RGGB, 12 bit) with exact car area-fraction masks into a RawStore.")
    p.add_argument("--n", type=int, required=True, help="number of scenes")
    p.add_argument("--seed", type=int, default=0, help="dataset seed (scene i depends only on seed and i)")
    p.add_argument("--out", required=True, help="output store (e.g. data/source.zarr)")
    p.add_argument("--size", type=int, default=1024, help="scene side in source pixels (even, default 1024)")
    p.add_argument("--kinds", default="urban,suburban,rural", help="comma-separated scene types, cycled")
    p.add_argument("--workers", type=int, default=2, help="worker processes (bytes do not depend on it)")
    p.add_argument("--contact-sheet", dest="contact_sheet", default=None, help="also write a contact sheet PNG")
    p.add_argument("--real-dir", default=None, help="KIT AIS folder for the real row of the contact sheet "
                   "(default data/real/kit_ais of the working directory, when present)")
    p.add_argument("--camera", default=None, help="source camera profile (JSON, or a params.yaml with "
                   "source.camera); default: the Hasselblad L1D-20c of docs/emulation.md")
    p.add_argument("--overwrite", action="store_true", help="replace an existing output")
    add_codec_arguments(p)
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from metraw.io.store import RawStore
    from metraw.progress import progress_bar
    from metraw.scenes import generate, scene_camera

    if args.n < 1:
        raise MetrawError(f"--n must be >= 1, got {args.n}")
    if args.seed < 0:
        raise MetrawError(f"--seed must be >= 0, got {args.seed}")
    if args.size < 16 or args.size % 2:
        raise MetrawError(f"--size must be an even number >= 16, got {args.size}")
    if args.workers < 1:
        raise MetrawError(f"--workers must be >= 1, got {args.workers}")
    codec = StoreCodec(args)
    kinds = tuple(k.strip() for k in args.kinds.split(",") if k.strip())
    if args.camera:
        from metraw.io import load_camera

        camera = load_camera(args.camera)
    else:
        camera = scene_camera()
    t0 = time.perf_counter()
    with RawStore.create(args.out, overwrite=args.overwrite, **codec.create_kwargs()) as store:
        store.set_attrs(generator="metraw.scenes", seed=args.seed, n=args.n, size_px=args.size, kinds=list(kinds),
                        **codec.attrs())
        images = generate(args.n, args.seed, size_px=args.size, camera=camera, kinds=kinds, workers=args.workers)
        for img in progress_bar(images, total=args.n, desc="scenes"):
            store.append(codec.mark(img))
    dt = time.perf_counter() - t0
    print(f"metraw scenes: wrote {args.n} scenes of {args.size}x{args.size} to {args.out} in {dt:.1f} s "
          f"({dt / args.n:.3f} s/scene, {args.workers} workers)")
    if args.contact_sheet:
        from metraw.scenes.contact_sheet import scenes_contact_sheet

        real = Path(args.real_dir) if args.real_dir else DEFAULT_REAL_DIR
        scenes_contact_sheet(RawStore.open(args.out), args.contact_sheet, real_dir=real if real.is_dir() else None)
        print(f"metraw scenes: contact sheet {args.contact_sheet}")
    return 0
