"""``metraw decode INPUT OUTPUT``: a ``.mraw`` file to a uint16 TIFF with the profile embedded, or a store
(``.zarr``) to a working copy with its raw array uncompressed (``metraw.io.store.write_decoded_copy``)."""

from __future__ import annotations

from pathlib import Path

from metraw.errors import MetrawError


def register(sub) -> None:
    p = sub.add_parser("decode", help="decode a .mraw file to a raw TIFF (profile embedded), or a store to an "
                                      "uncompressed working copy")
    p.add_argument("input", help=".mraw file, or metraw store (.zarr directory)")
    p.add_argument("output", help="TIFF for a .mraw input; store (.zarr) for a store input")
    p.add_argument("--threads", type=int, default=1,
                   help="codec threads decoding each image of a store (default 1; the bytes do not depend on it)")
    p.add_argument("--overwrite", action="store_true")
    p.set_defaults(func=run)


def run(args) -> int:
    path = Path(args.input)
    if not path.exists():
        raise MetrawError(f"input {path} does not exist")
    if Path(args.output).exists() and not args.overwrite:
        raise MetrawError(f"output {args.output} already exists (use --overwrite to replace it)")
    if path.is_dir():
        return _decode_store(path, args)
    from metraw.io import read_mraw
    from metraw.io.tiff import write_tiff

    image = read_mraw(path)
    write_tiff(args.output, image, overwrite=args.overwrite)
    print(f"{args.output}: {image.shape[0]} x {image.shape[1]} uint16 DN")
    return 0


def _decode_store(path: Path, args) -> int:
    import time

    from metraw import codec
    from metraw.io.store import RawStore, write_decoded_copy

    if args.threads < 1:
        raise MetrawError(f"--threads must be >= 1, got {args.threads}")
    if not RawStore.is_store(path):
        raise MetrawError(f"input {path} is a directory but not a metraw store (no zarr.json)")
    t0 = time.perf_counter()
    with codec.threads(args.threads):
        copy = write_decoded_copy(path, args.output, overwrite=args.overwrite)
    print(f"metraw decode: {len(copy)} images of {path} to {args.output} (raw array uncompressed) "
          f"in {time.perf_counter() - t0:.1f} s")
    return 0
