#!/usr/bin/env bash
# Splat-format fixtures written by an outside implementation, PlayCanvas's
# `@playcanvas/splat-transform` (npm), for our readers and writers of splat formats.
#
# How to run (from anywhere; needs node >= 20 with npm, python3 with only its standard library,
# and cargo to build our exporter; no GPU):
#
#   ST_DIR=$(mktemp -d) SPZ_ST_DIR=$(mktemp -d)
#   (cd "$ST_DIR" && npm init -y >/dev/null && npm install @playcanvas/splat-transform@3.7.0)
#   (cd "$SPZ_ST_DIR" && npm init -y >/dev/null &&
#    npm install --ignore-scripts @playcanvas/splat-transform@2.7.1)
#   ST_DIR="$ST_DIR" SPZ_ST_DIR="$SPZ_ST_DIR" bash scripts/make_splat_fixtures.sh
#
# SPZ comes from splat-transform 2.7.1: it writes and reads SPZ through Niantic's library
# converting between the PLY frame (x right, y down, z forward) and the frame SPZ defines for
# its contents (x right, y up, z back), as Niantic's ply_to_spz does. splat-transform 3
# (3.4.2 to 3.7.0) stores the PLY frame unconverted, so its SPZ files are not used here.
#
# (splat-transform 3.7.0 declares node >= 22; it runs on node 20 with an EBADENGINE warning.
# It brings @adobe/spz 0.2.3, the official Niantic/Adobe SPZ encoder compiled to WebAssembly,
# which splat-transform itself uses to write .spz.)
#
# Writes, removing the folder first, crates/gs-core/tests/fixtures/splats/:
#
#   source.ply                   50 Gaussians, INRIA 3DGS binary_little_endian PLY, SH degree 3,
#                                float32 properties in INRIA order
#                                  x y z nx ny nz f_dc_0..2 f_rest_0..44 opacity scale_0..2 rot_0..3
#                                (normals 0; rot_0 = w; quaternions deliberately NOT unit: norm in
#                                [0.5, 2], some with negative w; opacity logits in [-4, 4];
#                                log-scales in [-5, -1]; f_dc in [-1.5, 1.5]; f_rest in [-0.3, 0.3];
#                                positions in [-2, 2]); from a seeded xorshift PRNG (below)
#   unit.ply                     the same 50 Gaussians with each quaternion divided by its norm
#                                (float64, then stored as float32); see unit.splat
#   source.compressed.ply        SuperSplat compressed PLY (chunk/vertex/sh elements) - REORDERED
#                                (Morton order), so match Gaussians by position, not index
#   source.splat                 antimatter15 .splat (32 bytes a Gaussian, no SH); splat-transform
#                                does not normalise quaternions here, so with source.ply's
#                                non-unit quaternions the rotation bytes saturate (clamped to 0/255)
#   unit.splat                   .splat of unit.ply (unit quaternions): the meaningful .splat fixture
#   source.v2.spz                SPZ version 2 (gzip, 16-byte header, 3-byte xyz rotations), written
#                                by splat-transform 2.7.1's @adobe/spz (saveSpzToBuffer) directly
#                                (the CLI writes only versions 3 and 4), with the options and
#                                data layout splat-transform 2.7.1 uses (from RDF)
#   source.v3.spz                SPZ version 3 (gzip, smallest-three rotations): splat-transform
#                                2.7.1 --spz-version 3
#   source.v4.spz                SPZ version 4 (NGSP plaintext 32-byte header + TOC + ZSTD
#                                streams): splat-transform 2.7.1 --spz-version 4 (its default)
#   source.sog                   PlayCanvas SOG bundle (zip of meta.json + lossless WebP images),
#                                written with --gpu cpu --max-workers 0; splat-transform's CPU
#                                k-means draws on Math.random and its zip writer stamps the current
#                                time, so for reproducible bytes node preloads a module that seeds
#                                Math.random (mulberry32) and pins `new Date()` to 2000-01-01;
#                                REORDERED (Morton), very lossy (SH palette), for reading only
#   ours.sog                     OUR SOG writer's file of source.ply (clipgaussian-3d export, built
#                                here with cargo): its .decoded.ply is splat-transform's reading
#                                of what we write; Gaussians in source.ply's order
#   source.glb                   glTF 2.0 binary with KHR_gaussian_splatting; note: written in
#                                PlayCanvas engine space, i.e. rotated 180 degrees about Z relative
#                                to the PLY (x -> -x, y -> -y, quaternion and SH rotated too);
#                                splat-transform cannot read .glb back, so it has no .decoded.ply
#   <name>.decoded.ply           splat-transform's own reading of <name>, written back as a plain
#                                float32 PLY: values after that format's quantisation. Its
#                                properties are in splat-transform's order, not INRIA's:
#                                  x y z rot_0..3 scale_0..2 opacity f_dc_0..2 [f_rest_0..N]
#                                (no nx/ny/nz; .splat has no f_rest). Rows are in the order of
#                                <name> itself (for compressed PLY and SOG that is Morton order).
#
# .ply, .compressed.ply, .splat and .sog are read and written by splat-transform in one frame,
# the PLY frame. The .spz files hold SPZ's own frame (y and z negated, quaternions and SH
# turned with them); their .decoded.ply, splat-transform 2.7.1's reading, is in the PLY frame.
set -euo pipefail

: "${ST_DIR:?set ST_DIR to the folder where @playcanvas/splat-transform@3.7.0 is npm-installed}"
: "${SPZ_ST_DIR:?set SPZ_ST_DIR to the folder where @playcanvas/splat-transform@2.7.1 is npm-installed}"
ST="$ST_DIR/node_modules/.bin/splat-transform"
ST2="$SPZ_ST_DIR/node_modules/.bin/splat-transform"
SPZ_JS="$SPZ_ST_DIR/node_modules/@adobe/spz/dist/spz.js"
[ -x "$ST" ] || { echo "no splat-transform at $ST" >&2; exit 1; }
[ -x "$ST2" ] || { echo "no splat-transform at $ST2" >&2; exit 1; }
[ -f "$SPZ_JS" ] || { echo "no @adobe/spz at $SPZ_JS" >&2; exit 1; }
"$ST" --version 2>&1 | grep -q '3\.7\.0' || { echo "expected splat-transform 3.7.0" >&2; exit 1; }
"$ST2" --version 2>&1 | grep -q '2\.7\.1' || { echo "expected splat-transform 2.7.1" >&2; exit 1; }

ROOT=$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)
OUT="$ROOT/crates/gs-core/tests/fixtures/splats"
rm -rf "$OUT"
mkdir -p "$OUT"
cd "$OUT"

# --- a. the source PLY (and its unit-quaternion twin) -------------------------------------
python3 - <<'PY'
import math
import struct

N = 50
SH_REST = 45
NAMES = (["x", "y", "z", "nx", "ny", "nz", "f_dc_0", "f_dc_1", "f_dc_2"]
         + [f"f_rest_{i}" for i in range(SH_REST)]
         + ["opacity", "scale_0", "scale_1", "scale_2", "rot_0", "rot_1", "rot_2", "rot_3"])


class XorShift64Star:
    """xorshift64* (Vigna); uniform() gives a double in [0, 1) from the top 53 bits."""

    def __init__(self, seed):
        self.s = seed & 0xFFFFFFFFFFFFFFFF or 1

    def next_u64(self):
        x = self.s
        x ^= x >> 12
        x ^= (x << 25) & 0xFFFFFFFFFFFFFFFF
        x ^= x >> 27
        self.s = x
        return (x * 0x2545F4914F6CDD1D) & 0xFFFFFFFFFFFFFFFF

    def uniform(self, lo=0.0, hi=1.0):
        return lo + (hi - lo) * ((self.next_u64() >> 11) / float(1 << 53))


rng = XorShift64Star(0x5EED_3D65_0000_0050)
rows = []
for i in range(N):
    pos = [rng.uniform(-2.0, 2.0) for _ in range(3)]
    f_dc = [rng.uniform(-1.5, 1.5) for _ in range(3)]
    f_rest = [rng.uniform(-0.3, 0.3) for _ in range(SH_REST)]
    opacity = rng.uniform(-4.0, 4.0)
    scale = [rng.uniform(-5.0, -1.0) for _ in range(3)]
    # a direction on S3 from 4 uniforms in [-1, 1] (rejected if too short), then a norm in [0.5, 2]
    while True:
        q = [rng.uniform(-1.0, 1.0) for _ in range(4)]
        n = math.sqrt(sum(c * c for c in q))
        if 0.2 < n <= 1.0:
            break
    norm = rng.uniform(0.5, 2.0)
    q = [c / n * norm for c in q]
    rows.append(pos + [0.0, 0.0, 0.0] + f_dc + f_rest + [opacity] + scale + q)

# a few hand-set rotations so the edge cases are surely there: identity, a negative-w quaternion
# whose largest component is w, and one whose largest |component| is a negative z
rows[0][-4:] = [1.0, 0.0, 0.0, 0.0]
rows[1][-4:] = [-1.2, 0.3, -0.2, 0.1]
rows[2][-4:] = [0.1, 0.2, -0.3, -0.9]


def write_ply(path, rows):
    header = ("ply\nformat binary_little_endian 1.0\n"
              f"element vertex {len(rows)}\n"
              + "".join(f"property float {p}\n" for p in NAMES)
              + "end_header\n")
    with open(path, "wb") as f:
        f.write(header.encode("ascii"))
        for r in rows:
            assert len(r) == len(NAMES)
            f.write(struct.pack(f"<{len(NAMES)}f", *r))


write_ply("source.ply", rows)

unit = []
for r in rows:
    q = [struct.unpack("<f", struct.pack("<f", c))[0] for c in r[-4:]]  # as stored in source.ply
    n = math.sqrt(sum(c * c for c in q))
    unit.append(r[:-4] + [c / n for c in q])
write_ply("unit.ply", unit)
PY

# --- b. every format splat-transform writes -----------------------------------------------
st() { "$ST" -q -w "$@"; }
st2() { "$ST2" -q -w "$@" 2>/dev/null; }
st source.ply source.compressed.ply
st source.ply source.splat
st unit.ply unit.splat
st2 --spz-version 3 source.ply source.v3.spz
st2 --spz-version 4 source.ply source.v4.spz
PRELOAD=$(mktemp --suffix=.mjs)
trap 'rm -f "$PRELOAD"' EXIT
cat >"$PRELOAD" <<'JS'
let seed = 0x9e3779b9;
Math.random = () => {
    seed = (seed + 0x6d2b79f5) | 0;
    let t = Math.imul(seed ^ (seed >>> 15), 1 | seed);
    t = (t + Math.imul(t ^ (t >>> 7), 61 | t)) ^ t;
    return ((t ^ (t >>> 14)) >>> 0) / 4294967296;
};
const RealDate = Date;
globalThis.Date = class extends RealDate {
    constructor(...a) { if (a.length === 0) { super(2000, 0, 1); } else { super(...a); } }
};
JS
NODE_OPTIONS="--import=$PRELOAD" st --gpu cpu --max-workers 0 source.ply source.sog
st source.ply source.glb

# SPZ version 2 through @adobe/spz directly, with splat-transform 2.7.1's GaussianCloud layout
# (quaternion xyzw, SH channel-inner) and pack options (from RDF, sh1Bits 5, shRestBits 4).
node --input-type=module - "$SPZ_JS" <<'JS'
import { readFileSync, writeFileSync } from 'node:fs';
import { pathToFileURL } from 'node:url';

const { default: createModule } = await import(pathToFileURL(process.argv[2]).href);
const spz = await createModule();

const buf = readFileSync('source.ply');
const end = buf.indexOf('end_header\n') + 'end_header\n'.length;
const header = buf.subarray(0, end).toString('ascii');
const names = [...header.matchAll(/^property float (\S+)$/gm)].map(m => m[1]);
const n = Number(/element vertex (\d+)/.exec(header)[1]);
const data = new Float32Array(buf.buffer.slice(buf.byteOffset + end, buf.byteOffset + end + n * names.length * 4));
const col = name => i => data[i * names.length + names.indexOf(name)];

const shDim = 15;
const cloud = {
    numPoints: n, shDegree: 3, antialiased: false, extensions: [],
    positions: new Float32Array(n * 3), scales: new Float32Array(n * 3),
    rotations: new Float32Array(n * 4), alphas: new Float32Array(n),
    colors: new Float32Array(n * 3), sh: new Float32Array(n * shDim * 3)
};
for (let i = 0; i < n; i++) {
    for (let k = 0; k < 3; k++) {
        cloud.positions[i * 3 + k] = col('xyz'[k])(i);
        cloud.scales[i * 3 + k] = col(`scale_${k}`)(i);
        cloud.colors[i * 3 + k] = col(`f_dc_${k}`)(i);
    }
    cloud.rotations[i * 4 + 0] = col('rot_1')(i);
    cloud.rotations[i * 4 + 1] = col('rot_2')(i);
    cloud.rotations[i * 4 + 2] = col('rot_3')(i);
    cloud.rotations[i * 4 + 3] = col('rot_0')(i);
    cloud.alphas[i] = col('opacity')(i);
    for (let c = 0; c < shDim; c++) {
        for (let ch = 0; ch < 3; ch++) {
            cloud.sh[i * shDim * 3 + c * 3 + ch] = col(`f_rest_${ch * shDim + c}`)(i);
        }
    }
}
const bytes = spz.saveSpzToBuffer(cloud, {
    version: 2, from: spz.CoordinateSystem.RDF, sh1Bits: 5, shRestBits: 4
});
if (!(bytes[0] === 0x1f && bytes[1] === 0x8b)) throw new Error('expected a gzip stream for SPZ v2');
writeFileSync('source.v2.spz', bytes);
JS

# --- c. our SOG, written by our exporter, for splat-transform to read ----------------------
cargo run -q --manifest-path "$ROOT/Cargo.toml" -p base-3dgs --bin clipgaussian-3d -- \
    export --model source.ply --out ours.sog >/dev/null

# --- d. splat-transform's reading of each, as a plain PLY ---------------------------------
for f in source.compressed.ply source.splat unit.splat source.sog ours.sog; do
    st "$f" "$f.decoded.ply"
done
for f in source.v2.spz source.v3.spz source.v4.spz; do
    st2 "$f" "$f.decoded.ply"
done

ls -l "$OUT"
du -sh "$OUT"
