"""``metraw ingest INPUT... --out STORE.zarr``: image files or directories into a RawStore, atomically."""

from __future__ import annotations

import time
from pathlib import Path

from metraw.cli._rawcodec import StoreCodec, add_arguments as add_codec_arguments


def register(subparsers) -> None:
    p = subparsers.add_parser("ingest", help="read raw / processed images (+ labels) into a metraw zarr store",
                              description="Files or directories (not recursive) -> one sharded zarr v3 store. "
                                          "Processed 8-bit RGB images become approximate raws of the stated camera.")
    p.add_argument("inputs", nargs="+", metavar="INPUT", help="image files or directories")
    p.add_argument("--out", required=True, help="output store (STORE.zarr); written atomically")
    p.add_argument("--camera", help="camera profile (JSON, or a params.yaml with source.camera); default: "
                                    "source.camera of ./params.yaml")
    p.add_argument("--labels", choices=("auto", "yolo", "mask", "none"), default="auto",
                   help="labels of processed images: YOLO .txt next to each image, or STEM_mask.png (default: auto)")
    p.add_argument("--car-class", action="append", default=[], metavar="NAME",
                   help="YOLO class counted as car, as the class-name file names it (repeatable; default: the "
                        "classes named car, truck, bus, minibus, van, pickup or vehicle)")
    p.add_argument("--gsd-m", type=float, default=None, help="ground sample distance of processed photos [m]")
    p.add_argument("--white-fraction", type=float, default=1.0,
                   help="fraction of the camera's saturation that sRGB white maps to (processed photos)")
    p.add_argument("--seed", type=int, default=0, help="seed of the approximate raws' sensor noise")
    p.add_argument("--meta", action="append", default=[], metavar="KEY=VALUE",
                   help="metadata of headerless .raw files (width, height, dtype, cfa_pattern, black_level_dn, "
                        "adc_bits, ...); repeatable")
    p.add_argument("--overwrite", action="store_true", help="replace an existing output store")
    add_codec_arguments(p)
    p.set_defaults(func=run)


def parse_meta(items: list[str]) -> dict[str, str]:
    from metraw.errors import MetrawError

    out = {}
    for item in items:
        key, sep, value = item.partition("=")
        if not sep or not key:
            raise MetrawError(f"--meta needs KEY=VALUE, got {item!r}")
        out[key.strip()] = value.strip()
    return out


def check_same_sensor(path: Path, profile, first: tuple[Path, str, int]) -> None:
    """One store holds one sensor: an image whose CFA pattern or ADC bit depth differs from the first image's
    is refused, naming both files (``MetrawError``)."""
    from metraw.errors import MetrawError

    name, pattern, bits = first
    if profile.cfa_pattern != pattern:
        raise MetrawError(f"{path}: CFA pattern {profile.cfa_pattern} differs from {pattern} of {name.name}; "
                          "one folder holds the raws of one sensor")
    if profile.adc_bits != bits:
        raise MetrawError(f"{path}: {profile.adc_bits}-bit data differ from the {bits} bits of {name.name}; "
                          "one folder holds the raws of one sensor")


def run(args) -> int:
    import sys

    from metraw.errors import MetrawError
    from metraw.io import image_files, load_camera, read_raw
    from metraw.io.store import RawStore
    from metraw.progress import progress_bar

    t0 = time.perf_counter()
    codec = StoreCodec(args)
    out = Path(args.out)
    if out.exists() and not args.overwrite:
        raise MetrawError(f"output {out} already exists (use --overwrite to replace it)")
    files = image_files(args.inputs)
    camera = load_camera(args.camera) if args.camera else None
    meta = parse_meta(args.meta)
    shapes, approx, car_boxes = set(), 0, 0
    first: tuple[Path, str, int] | None = None
    with RawStore.create(out, overwrite=args.overwrite, **codec.create_kwargs()) as store:
        for f in progress_bar(files, total=len(files), desc="ingest"):
            kwargs = dict(meta) if f.suffix.lower() in (".raw", ".bin") else {}
            image = read_raw(f, camera=camera, labels=args.labels, seed=args.seed, gsd_m=args.gsd_m,
                             white_fraction=args.white_fraction, car_classes=args.car_class or None, **kwargs)
            first = first or (f, image.profile.cfa_pattern, image.profile.adc_bits)
            check_same_sensor(f, image.profile, first)
            store.append(codec.mark(image))
            shapes.add(image.shape)
            approx += image.profile.approximate
            car_boxes += int(image.meta.get("car_boxes", 0))
        classes = {"car_classes": args.car_class} if args.car_class else {}
        store.set_attrs(ingest={"inputs": [str(i) for i in args.inputs], "files": [f.name for f in files],
                                "labels": args.labels, **classes, "seed": args.seed, "gsd_m": args.gsd_m,
                                "camera": camera.camera if camera else "default (params.yaml source.camera)"},
                        **({"camera_profile": camera.to_dict()} if camera is not None else {}),
                        **codec.attrs())
    dt = time.perf_counter() - t0
    print(f"ingested {len(files)} images ({approx} approximate, {car_boxes} car boxes) into {out} "
          f"in {dt:.1f} s; shapes (H, W): {sorted(shapes)}")
    if approx and args.gsd_m is None:
        print("metraw ingest: note: --gsd-m not given, processed images have unknown ground sample distance",
              file=sys.stderr)
    return 0
