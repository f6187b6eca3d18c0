"""``metraw decode INPUT.mraw OUTPUT.tif``: decode to a uint16 TIFF with the profile embedded."""

from __future__ import annotations

from pathlib import Path

from metraw.errors import MetrawError


def register(sub) -> None:
    p = sub.add_parser("decode", help="decode a .mraw file to a raw TIFF (profile embedded)")
    p.add_argument("input")
    p.add_argument("output")
    p.add_argument("--overwrite", action="store_true")
    p.set_defaults(func=run)


def run(args) -> int:
    from metraw.io import read_mraw
    from metraw.io.tiff import write_tiff

    path = Path(args.input)
    if not path.is_file():
        raise MetrawError(f"input {path} does not exist")
    if Path(args.output).exists() and not args.overwrite:
        raise MetrawError(f"output {args.output} already exists (use --overwrite to replace it)")
    image = read_mraw(path)
    write_tiff(args.output, image, overwrite=args.overwrite)
    print(f"{args.output}: {image.shape[0]} x {image.shape[1]} uint16 DN")
    return 0
