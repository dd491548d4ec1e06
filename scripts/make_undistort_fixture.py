#!/usr/bin/env python3
"""OpenCV's undistortion of COLMAP cameras, the oracle of `gs_core::dataset::undistort`.

gsplat's COLMAP parser (examples/datasets/colmap.py) undistorts a distorted perspective camera
with `cv2.getOptimalNewCameraMatrix(K, dist, (w, h), 0)` and
`cv2.initUndistortRectifyMap(K, dist, None, new_K, (w, h), cv2.CV_32FC1)`, then `cv2.remap`
with INTER_LINEAR. This script records, for one camera of each COLMAP model that has distortion
(SIMPLE_RADIAL twice, RADIAL, OPENCV twice, FULL_OPENCV, OPENCV_FISHEYE twice), what OpenCV computes:

  undistorted_points  [u, v, x, y]: pixel (u, v) of the distorted picture and its normalized
                      undistorted coordinates from cv2.undistortPoints (pinhole, default criteria:
                      5 fixed-point steps) or cv2.fisheye.undistortPoints (fisheye, default
                      criteria: 10 Newton steps, eps 1e-8, after clamping the distorted
                      radius to pi/2, which the strong fisheye's corners hit; a point whose
                      Newton steps do not converge or flip sign reads -1e6, -1e6)
  undistorted_points_exact
                      (pinhole only; not OpenCV) the true inverse of the distortion at the same
                      points, [u, v, x, y], by Newton's method in float64 from OpenCV's
                      answer, kept where it re-distorts to within 1e-9 pixel (else x, y are
                      null): it tells how far OpenCV's 5 steps are from the limit
  new_k, roi          pinhole: cv2.getOptimalNewCameraMatrix(K, dist, (w, h), alpha=0)
                      -> [fx, fy, cx, cy] and [x, y, w, h]; fisheye: new_k is K itself, no roi
  map                 [u, v, mapx, mapy] at every 7th destination pixel in x and y (and the last
                      column and row): cv2.initUndistortRectifyMap(K, dist, None, new_K, (w, h),
                      CV_32FC1) or cv2.fisheye.initUndistortRectifyMap(K, D, I, K, (w, h),
                      CV_32FC1); the float32 values written exactly
  remap               (one pinhole camera) a smooth RGB float32 picture (its formula is in the
                      file) remapped with cv2.remap(..., INTER_LINEAR, BORDER_CONSTANT, 0) by the
                      full map, sampled at the same pixels as "map", [u, v, r, g, b]

Every parameter is a dyadic fraction, so it is the same number in float32 (gsplat casts the
distortion to float32) and in float64.

How to run (PyPI only):
    python3 -m venv /tmp/cv && /tmp/cv/bin/pip install opencv-python-headless==4.11.0.86 numpy==2.2.6
    /tmp/cv/bin/python scripts/make_undistort_fixture.py [crates/gs-core/tests/fixtures/undistort_opencv.json]

OpenCV 4.x's remap rounds each map coordinate to 1/32 pixel (INTER_BITS = 5) before it weighs
the four neighbours; OpenCV 5.0 does not. Only the "remap" numbers depend on that (the file says
how much); everything else is the same in 4.11 and 5.0.
"""

import json
import math
import sys
from pathlib import Path

import cv2
import numpy as np

STEP = 7

# (model, width, height, COLMAP params in COLMAP's order)
CAMERAS = [
    ("SIMPLE_RADIAL", 64, 48, [52.5, 30.25, 25.75, 0.0625]),
    ("SIMPLE_RADIAL", 97, 53, [60.0, 50.5, 24.25, -0.15625]),
    ("RADIAL", 120, 90, [88.0, 57.5, 47.25, -0.1875, 0.03125]),
    ("OPENCV", 33, 71, [40.5, 44.25, 17.75, 33.5, -0.125, 0.015625, 0.0078125, -0.00390625]),
    (
        "OPENCV",
        90,
        70,
        [46.0, 43.5, 47.25, 33.75, -0.3125, 0.09375, -0.001953125, 0.0029296875],
    ),
    (
        "FULL_OPENCV",
        80,
        60,
        [58.0, 55.5, 41.25, 28.5, -0.125, 0.03125, -0.001953125, 0.00244140625,
         -0.00390625, 0.0625, -0.015625, 0.0078125],
    ),
    (
        "OPENCV_FISHEYE",
        64,
        48,
        [30.5, 29.75, 33.25, 22.5, 0.03125, -0.0078125, 0.001953125, -0.00048828125],
    ),
    (
        "OPENCV_FISHEYE",
        90,
        70,
        [28.0, 27.0, 44.5, 36.25, -0.0625, 0.125, -0.03125, 0.0078125],
    ),
]

REMAP_CAMERA = 5  # FULL_OPENCV

IMAGE_FORMULA = {
    "coordinates": "x = column index, y = row index (0-based); computed in float64, stored as float32",
    "r": "0.5 + 0.4 * sin(0.21 * x + 0.05 * y)",
    "g": "0.5 + 0.4 * cos(0.13 * x - 0.17 * y)",
    "b": "0.5 + 0.3 * sin(0.09 * x + 0.11 * y + 1.0)",
}


def split_params(model, params):
    """K and the distortion vector OpenCV is given, as gsplat builds them."""
    if model in ("SIMPLE_RADIAL", "RADIAL"):
        f, cx, cy = params[:3]
        fx = fy = f
        k = params[3:]
        dist = [k[0], k[1] if len(k) > 1 else 0.0, 0.0, 0.0]
    else:
        fx, fy, cx, cy = params[:4]
        dist = params[4:]  # OPENCV (k1 k2 p1 p2), FULL_OPENCV (k1 k2 p1 p2 k3 k4 k5 k6), fisheye k1..k4
    K = np.array([[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]], dtype=np.float64)
    return K, np.array(dist, dtype=np.float64)


def probe_points(w, h, cx, cy):
    pts = [
        (0.0, 0.0), (w - 1.0, 0.0), (0.0, h - 1.0), (w - 1.0, h - 1.0),
        ((w - 1) / 2.0, 0.0), ((w - 1) / 2.0, h - 1.0), (0.0, (h - 1) / 2.0), (w - 1.0, (h - 1) / 2.0),
        (cx, cy),
        (0.25 * w, 0.3 * h), (0.8 * w, 0.65 * h), (0.5 * w + 3.5, 0.5 * h - 2.25),
        (-0.5, -0.5), (w - 0.5, h - 0.5),
    ]
    return np.array(pts, dtype=np.float64)


def grid(n):
    g = list(range(0, n, STEP))
    if g[-1] != n - 1:
        g.append(n - 1)
    return g


def f32(v):
    """A float32 written exactly (as the float64 holding it)."""
    return float(np.float32(v))


def synthetic_image(w, h):
    y, x = np.mgrid[0:h, 0:w].astype(np.float64)
    r = 0.5 + 0.4 * np.sin(0.21 * x + 0.05 * y)
    g = 0.5 + 0.4 * np.cos(0.13 * x - 0.17 * y)
    b = 0.5 + 0.3 * np.sin(0.09 * x + 0.11 * y + 1.0)
    return np.stack([r, g, b], axis=-1).astype(np.float32)


def bilinear_exact(img, mx, my):
    """Bilinear sampling with unrounded weights, zero outside the picture (float64)."""
    h, w = img.shape[:2]
    x0 = math.floor(mx)
    y0 = math.floor(my)
    fx = mx - x0
    fy = my - y0
    out = np.zeros(img.shape[2], dtype=np.float64)
    for dy, wy in ((0, 1.0 - fy), (1, fy)):
        for dx, wx in ((0, 1.0 - fx), (1, fx)):
            xx, yy = x0 + dx, y0 + dy
            if 0 <= xx < w and 0 <= yy < h:
                out += wx * wy * img[yy, xx].astype(np.float64)
    return out


def distort(dist, x, y):
    """OpenCV's pinhole distortion of a normalized point and its Jacobian."""
    k1, k2, p1, p2, k3, k4, k5, k6 = list(dist) + [0.0] * (8 - len(dist))
    r2 = x * x + y * y
    num = 1 + ((k3 * r2 + k2) * r2 + k1) * r2
    den = 1 + ((k6 * r2 + k5) * r2 + k4) * r2
    rad = num / den
    dnum = k1 + (2 * k2 + 3 * k3 * r2) * r2
    dden = k4 + (2 * k5 + 3 * k6 * r2) * r2
    drad = (dnum * den - num * dden) / (den * den)  # d rad / d r2
    xd = x * rad + 2 * p1 * x * y + p2 * (r2 + 2 * x * x)
    yd = y * rad + p1 * (r2 + 2 * y * y) + 2 * p2 * x * y
    j = np.array([
        [rad + 2 * x * x * drad + 2 * p1 * y + 6 * p2 * x, 2 * x * y * drad + 2 * p1 * x + 2 * p2 * y],
        [2 * x * y * drad + 2 * p1 * x + 2 * p2 * y, rad + 2 * y * y * drad + 6 * p1 * y + 2 * p2 * x],
    ])
    return xd, yd, j


def exact_inverse(dist, xd, yd, x, y, fx, fy):
    """Newton's method from (x, y); None, None where it does not reach 1e-9 pixel."""
    for _ in range(100):
        ex, ey, j = distort(dist, x, y)
        try:
            dx, dy = np.linalg.solve(j, [ex - xd, ey - yd])
        except np.linalg.LinAlgError:
            return None, None
        x, y = x - dx, y - dy
    ex, ey, _ = distort(dist, x, y)
    if math.hypot((ex - xd) * fx, (ey - yd) * fy) < 1e-9:
        return float(x), float(y)
    return None, None


def camera_entry(index, model, w, h, params):
    K, dist = split_params(model, params)
    fx, fy, cx, cy = K[0, 0], K[1, 1], K[0, 2], K[1, 2]
    pts = probe_points(w, h, cx, cy)
    entry = {"model": model, "width": w, "height": h, "params": params}
    fisheye = model == "OPENCV_FISHEYE"
    if fisheye:
        und = cv2.fisheye.undistortPoints(pts.reshape(-1, 1, 2), K, dist).reshape(-1, 2)
        new_k = K
        mapx, mapy = cv2.fisheye.initUndistortRectifyMap(K, dist, np.eye(3), K, (w, h), cv2.CV_32FC1)
        entry["new_k"] = [fx, fy, cx, cy]
    else:
        und = cv2.undistortPoints(pts.reshape(-1, 1, 2), K, dist).reshape(-1, 2)
        exact = [exact_inverse(dist, (u - cx) / fx, (v - cy) / fy, x, y, fx, fy)
                 for (u, v), (x, y) in zip(pts, und)]
        new_k, roi = cv2.getOptimalNewCameraMatrix(K, dist, (w, h), 0)
        mapx, mapy = cv2.initUndistortRectifyMap(K, dist, None, new_k, (w, h), cv2.CV_32FC1)
        entry["new_k"] = [float(new_k[0, 0]), float(new_k[1, 1]), float(new_k[0, 2]), float(new_k[1, 2])]
        entry["roi"] = [int(v) for v in roi]
    entry["undistorted_points"] = [
        [float(p[0]), float(p[1]), float(q[0]), float(q[1])] for p, q in zip(pts, und)
    ]
    if not fisheye:
        entry["undistorted_points_exact"] = [
            [float(p[0]), float(p[1]), q[0], q[1]] for p, q in zip(pts, exact)
        ]
    gu, gv = grid(w), grid(h)
    entry["map"] = [[u, v, f32(mapx[v, u]), f32(mapy[v, u])] for v in gv for u in gu]

    if index == REMAP_CAMERA:
        img = synthetic_image(w, h)
        out = cv2.remap(img, mapx, mapy, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=0)
        samples = []
        worst = 0.0
        worst_rounded = 0.0
        for v in gv:
            for u in gu:
                got = out[v, u].astype(np.float64)
                exact = bilinear_exact(img, float(mapx[v, u]), float(mapy[v, u]))
                worst = max(worst, float(np.max(np.abs(exact - got))))
                # OpenCV 4.x: round(32 * m) half to even, then integer part and a 1/32 fraction
                qx, qy = int(np.rint(mapx[v, u] * 32.0)), int(np.rint(mapy[v, u] * 32.0))
                rounded = bilinear_exact(img, (qx >> 5) + (qx & 31) / 32.0, (qy >> 5) + (qy & 31) / 32.0)
                worst_rounded = max(worst_rounded, float(np.max(np.abs(rounded - got))))
                samples.append([u, v] + [f32(c) for c in out[v, u]])
        # OpenCV 4.x's rounding of the map to 1/32 pixel moves a sample by at most 1/64 pixel
        # in x and in y, so it changes a value by at most 2/64 of the largest step between
        # neighbouring pixels: steps inside the picture where the sample lies in
        # [0, w-1] x [0, h-1], and steps to the zero border too where it does not.
        f64 = img.astype(np.float64)
        padded = np.pad(f64, ((1, 1), (1, 1), (0, 0)))
        step_in = max(np.max(np.abs(np.diff(f64, axis=a))) for a in (0, 1))
        step_out = max(np.max(np.abs(np.diff(padded, axis=a))) for a in (0, 1))
        entry["remap"] = {
            "image": IMAGE_FORMULA,
            "call": "cv2.remap(img, mapx, mapy, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=0)",
            "samples": samples,
            "max_abs_diff_vs_exact_bilinear": worst,
            "max_abs_diff_vs_bilinear_at_1_32_pixel": worst_rounded,
            "tolerance_inside": 2.0 * float(step_in) / 64.0 + 1e-6,
            "tolerance_outside": 2.0 * float(step_out) / 64.0 + 1e-6,
            "note": "samples are [u, v, r, g, b] at the pixels of 'map'. OpenCV 4.x rounds 32*mapx "
            "and 32*mapy to integers (half to even) before weighing the four neighbours with "
            "float weights; a neighbour outside the picture reads borderValue 0 and keeps its "
            "weight. An exact bilinear sampler (zero outside) agrees within tolerance_inside "
            "where 0 <= mapx <= width-1 and 0 <= mapy <= height-1, else within tolerance_outside; "
            "one that first rounds 32*m the same way agrees within "
            "max_abs_diff_vs_bilinear_at_1_32_pixel (float32 rounding; OpenCV 4.x only).",
        }
    return entry


def main():
    root = Path(__file__).resolve().parent.parent
    out = Path(sys.argv[1]) if len(sys.argv) > 1 else root / "crates/gs-core/tests/fixtures/undistort_opencv.json"
    data = {
        "opencv_version": cv2.__version__,
        "numpy_version": np.__version__,
        "generator": "scripts/make_undistort_fixture.py",
        "map_step": STEP,
        "cameras": [camera_entry(i, *c) for i, c in enumerate(CAMERAS)],
    }
    text = json.dumps(data, separators=(",", ":"))
    # one camera entry field per line keeps diffs readable without bloating the file
    text = text.replace(',"cameras":[', ',\n"cameras":[\n').replace('},{"model"', '},\n{"model"')
    out.write_text(text + "\n")
    print(f"wrote {out} ({len(text)} bytes)")


if __name__ == "__main__":
    main()
