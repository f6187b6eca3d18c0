"""Statistics of the synthetic scenes side by side with the real KIT AIS aerial photos.

    nice -n 5 python benchmarks/scene_stats.py [--n 30] [--seed 0] [--store data/source.zarr]

KIT AIS: data/real/kit_ais of the repository (see its SOURCE.txt; CC-BY 3.0 KIT AIS data set, crops of
nadir aerial photos of Munich, ~12.5 cm GSD), converted to approximate raws by metraw.io.read_raw.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from metraw.scenes import generate
from metraw.scenes.stats import F_BAND_PER_M, format_table, summarise

KIT = Path(__file__).resolve().parents[1] / "data" / "real" / "kit_ais"


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--n", type=int, default=30)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--store", default=None, help="read scenes from a store instead of generating")
    args = ap.parse_args()
    if args.store:
        from metraw.io.store import RawStore

        store = RawStore.open(args.store)
        images = [store[i] for i in range(min(args.n, len(store)))]
    else:
        images = list(generate(args.n, args.seed, workers=2))
    rows = summarise(images, KIT if KIT.is_dir() else None)
    print(f"green PSD slope fitted over {F_BAND_PER_M[0]}-{F_BAND_PER_M[1]} cycles/m; KIT sizes from YOLO class 'car' "
          f"boxes x 0.125 m, synthetic from oriented generator dims (class car) and mask components (all vehicles)")
    print(format_table(rows))


if __name__ == "__main__":
    main()
