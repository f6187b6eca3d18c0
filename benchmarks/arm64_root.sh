#!/usr/bin/env bash
# A 64-bit ARM Python for benchmarks/codec_cpu_models.py --arm64-root DIR: the codec's portable C path and numba loops
# run on ARM (NEON) under qemu-aarch64, to check they write the same bytes as on this x86-64 host (issue #52).
#
# Makes DIR/root (Debian bookworm's arm64 Python 3.11 and the libraries it links, unpacked, not installed), DIR/site
# (the arm64 wheels of the host's versions of metraw's codec dependencies), DIR/src (a copy of src/metraw with the
# extension cross-compiled for aarch64 with pyproject's flags plus -Wall -Werror). Nothing is installed on the host
# but qemu-user and the cross compiler; the arm64 package lists are added to apt (dpkg --add-architecture arm64).
# Needs: Debian or Ubuntu, root, Python 3.11 as the host's (the wheels' ABI), network access to the package mirrors
# and PyPI.   Run: benchmarks/arm64_root.sh DIR
set -euo pipefail
dir=${1:?usage: benchmarks/arm64_root.sh DIR}
repo=$(cd "$(dirname "$0")/.." && pwd)
py=${PYTHON:-python3}
if [ "$("$py" -c 'import sys; print(sys.version_info[:2] == (3, 11))')" != True ]; then
    echo "arm64_root.sh: the host's Python ($py) must be 3.11, the arm64 Python's version" >&2; exit 2
fi
mkdir -p "$dir/debs" "$dir/root" "$dir/site" "$dir/src"
dir=$(cd "$dir" && pwd)

apt-get install -y -q qemu-user gcc-aarch64-linux-gnu >/dev/null
dpkg --print-foreign-architectures | grep -qx arm64 || dpkg --add-architecture arm64
apt-get update -q >/dev/null
(cd "$dir/debs" && apt-get download -q \
    python3.11-minimal:arm64 libpython3.11-minimal:arm64 libpython3.11-stdlib:arm64 libc6:arm64 libexpat1:arm64 \
    zlib1g:arm64 libffi8:arm64 libssl3:arm64 libbz2-1.0:arm64 liblzma5:arm64 libgcc-s1:arm64 libstdc++6:arm64 \
    libuuid1:arm64 libcrypt1:arm64 libsqlite3-0:arm64 libtinfo6:arm64 libncursesw6:arm64 libreadline8:arm64 \
    libnsl2:arm64 libtirpc3:arm64 libgssapi-krb5-2:arm64 libkrb5-3:arm64 libk5crypto3:arm64 libkrb5support0:arm64 \
    libcom-err2:arm64 libkeyutils1:arm64 2>&1 >/dev/null) | { grep -v unsandboxed >&2 || true; }   # apt's note on root
for deb in "$dir"/debs/*.deb; do dpkg-deb -x "$deb" "$dir/root"; done

# the host's versions of what the codec, its benchmark frames and the fixtures' test module import
pins=$("$py" - <<'EOF'
from importlib.metadata import version
names = ("numpy", "numba", "llvmlite", "scipy", "pyyaml", "tqdm", "google-crc32c", "rawpy", "tifffile", "imagecodecs",
         "pytest", "iniconfig", "pluggy", "packaging", "pygments")
print(" ".join(f"{n}=={version(n)}" for n in names))
EOF
)
# shellcheck disable=SC2086
"$py" -m pip install -q --upgrade --target "$dir/site" --python-version 3.11 --implementation cp --only-binary=:all: \
    --no-deps --platform manylinux2014_aarch64 --platform manylinux_2_17_aarch64 --platform manylinux_2_27_aarch64 \
    --platform manylinux_2_28_aarch64 $pins

rm -rf "$dir/src/metraw"
cp -r "$repo/src/metraw" "$dir/src/"
find "$dir/src" \( -name __pycache__ -o -name "*.so" \) -prune -exec rm -rf {} +
read -r -a build < <("$py" -c "
import tomllib
ext = tomllib.load(open('$repo/pyproject.toml', 'rb'))['tool']['setuptools']['ext-modules'][0]
print(' '.join(ext['extra-compile-args'] + [s.rsplit('/', 1)[1] for s in ext['sources']]))")
(cd "$dir/src/metraw/codec" && aarch64-linux-gnu-gcc "${build[@]}" -Wall -Werror -fPIC -shared \
    -o _simd.cpython-311-aarch64-linux-gnu.so)
echo "arm64 Python in $dir: run python benchmarks/codec_cpu_models.py --models arm64 --arm64-root $dir"
