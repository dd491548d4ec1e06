#!/usr/bin/env python3
"""A small COLMAP scene written by the real COLMAP library (pycolmap), the fixture of our COLMAP reader.

Writes, deterministically, under crates/base-3dgs/tests/fixtures/colmap_pycolmap/ (the folder is
removed and written anew):

  sparse/0/       the reconstruction in COLMAP's TEXT format, by pycolmap's own writer
                  (`Reconstruction.write_text`): cameras.txt, images.txt, points3D.txt, and, as
                  COLMAP >= 3.12 writes them, rigs.txt and frames.txt (one trivial rig per
                  camera, one trivial frame per image)
  sparse_bin/0/   the same reconstruction in BINARY format (`Reconstruction.write_binary`):
                  cameras.bin, images.bin, points3D.bin, rigs.bin, frames.bin
  images/         one small RGB PNG per registered image, of its camera's size, a smooth pattern
                  (formula in `picture` below)
  expected.json   what a reader should get, taken from pycolmap's reading of sparse_bin/0 (the
                  text files are checked to read back the same); schema:
                    "pycolmap": version string
                    "images": sorted by name, each
                      {"name", "image_id", "camera_id", "model", "width", "height",
                       "params" (COLMAP's order for the model),
                       "rotation" (3x3 world-to-camera, rows; `image.cam_from_world().rotation.matrix()`),
                       "translation" (3, world-to-camera: x_cam = R x_world + t),
                       "quaternion_wxyz" (as in images.txt), "center" (camera centre in world),
                       "num_points2D", "num_points3D" (observations with a 3D point)}
                    "cameras": sorted by camera_id, each
                      {"camera_id", "model", "width", "height", "params",
                       "distortion" (OpenCV's dist vector [k1, k2, p1, p2]; null for PINHOLE),
                       "undistorted" (null for PINHOLE, which needs none; else
                         {"new_k": [fx, fy, cx, cy], "roi": [x, y, w, h]} from
                         cv2.getOptimalNewCameraMatrix(K, dist, (w, h), 0))}
                    "points3D": sorted by id, each {"id", "xyz", "rgb", "error", "track": [[image_id, point2D_idx], ...]}

Scene: 3 cameras (1 SIMPLE_RADIAL 40x30, 2 OPENCV 36x28, 3 PINHOLE 32x24), 4 images (ids 1..4,
named so that name order is not id order; ids 1 and 2 share camera 1), each looking at the
origin from about 3 units away with a roll about its axis; 8 colored 3D points near the origin,
each observed by 3 or 4 images (the 2D points are the true projections moved by up to 0.05 px, so
the reprojection errors are small but not zero); every image also has one keypoint with no 3D
point (point3D_id -1 in images.txt), first in its list.

Run (pinned):
    python3 -m venv /tmp/pycolmap && /tmp/pycolmap/bin/pip install pycolmap==4.2.1 numpy==2.2.6 \
        pillow==11.3.0 opencv-python-headless==4.11.0.86 \
        && /tmp/pycolmap/bin/python scripts/make_colmap_fixture.py
"""

import json
import math
import shutil
from pathlib import Path

import cv2
import numpy as np
import pycolmap
from PIL import Image as PILImage

OUT = Path(__file__).resolve().parent.parent / "crates/base-3dgs/tests/fixtures/colmap_pycolmap"

# camera_id -> (model, width, height, params in COLMAP's order)
CAMERAS = {
    1: ("SIMPLE_RADIAL", 40, 30, [36.0, 20.25, 14.75, -0.04]),
    2: ("OPENCV", 36, 28, [31.5, 32.25, 17.75, 13.5, -0.03, 0.012, 0.0015, -0.001]),
    3: ("PINHOLE", 32, 24, [29.0, 28.5, 16.0, 12.25]),
}

# image_id -> (name, camera_id, camera centre in world, roll about the optical axis in degrees)
IMAGES = {
    1: ("view_c.png", 1, [2.1, -2.0, 0.9], 7.0),
    2: ("view_a.png", 1, [-1.4, -2.5, 1.2], -11.0),
    3: ("view_d.png", 2, [2.6, 1.1, -0.8], 4.0),
    4: ("view_b.png", 3, [-2.2, 1.6, 1.5], -6.0),
}

POINTS = [
    ([0.0, 0.0, 0.0], [200, 40, 40]),
    ([0.5, -0.3, 0.2], [40, 200, 40]),
    ([-0.45, 0.35, -0.25], [40, 40, 200]),
    ([0.3, 0.45, -0.4], [230, 210, 30]),
    ([-0.35, -0.5, 0.3], [30, 210, 220]),
    ([0.6, 0.2, 0.45], [210, 30, 220]),
    ([-0.2, 0.6, 0.5], [128, 128, 128]),
    ([0.15, -0.55, -0.5], [255, 160, 90]),
]


def look_at(center, roll_deg):
    """World-to-camera rotation of a COLMAP camera (x right, y down, z forward) at `center`
    looking at the origin, world z up, then rolled about its optical axis."""
    c = np.asarray(center, dtype=np.float64)
    z = -c / np.linalg.norm(c)
    x = np.cross(z, [0.0, 0.0, 1.0])
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    r = np.stack([x, y, z])  # rows: camera axes in world coordinates
    a = math.radians(roll_deg)
    roll = np.array([[math.cos(a), -math.sin(a), 0.0], [math.sin(a), math.cos(a), 0.0], [0.0, 0.0, 1.0]])
    return roll @ r


def observes(point_index, image_index):
    """Point k is seen by every image but the one of index k % 5 (none when that is 4)."""
    return image_index != point_index % 5


def picture(width, height, seed):
    """A smooth RGB pattern, uint8."""
    v, u = np.mgrid[0:height, 0:width].astype(np.float64)
    r = 127.5 + 127.5 * np.sin(0.21 * u + 0.13 * v + seed)
    g = 127.5 + 127.5 * np.cos(0.17 * v - 0.09 * u + 0.5 * seed)
    b = 255.0 * (u + v + 3.0 * seed) / (width + height + 12.0)
    return np.clip(np.rint(np.stack([r, g, b], axis=-1)), 0, 255).astype(np.uint8)


def build():
    rec = pycolmap.Reconstruction()
    for camera_id, (model, w, h, params) in CAMERAS.items():
        cam = pycolmap.Camera(model=model, width=w, height=h, params=params, camera_id=camera_id)
        rec.add_camera_with_trivial_rig(cam)

    poses = {}
    keypoints = {}  # image_id -> list of (xy, point index or None)
    for image_index, (image_id, (name, camera_id, center, roll)) in enumerate(IMAGES.items()):
        rot = look_at(center, roll)
        t = -rot @ np.asarray(center, dtype=np.float64)
        pose = pycolmap.Rigid3d(pycolmap.Rotation3d(rot), t)
        poses[image_id] = pose
        cam = rec.cameras[camera_id]
        w, h = cam.width, cam.height
        kps = [(np.array([2.5 + image_index, h - 3.5]), None)]  # a keypoint with no 3D point
        for k, (xyz, _) in enumerate(POINTS):
            if not observes(k, image_index):
                continue
            xy = np.asarray(cam.img_from_cam(pose * np.asarray(xyz, dtype=np.float64)), dtype=np.float64)
            assert 0.5 < xy[0] < w - 0.5 and 0.5 < xy[1] < h - 0.5, (name, k, xy)
            # a small deterministic offset so reprojection errors are not zero
            xy = xy + 0.05 * np.array([math.sin(1.7 * k + image_index), math.cos(0.9 * k - image_index)])
            kps.append((xy, k))
        keypoints[image_id] = kps
        points2d = pycolmap.Point2DList([pycolmap.Point2D(xy) for xy, _ in kps])
        image = pycolmap.Image(name=name, points2D=points2d, camera_id=camera_id, image_id=image_id)
        rec.add_image_with_trivial_frame(image, pose)

    for k, (xyz, rgb) in enumerate(POINTS):
        elements = [
            pycolmap.TrackElement(image_id, idx)
            for image_id, kps in keypoints.items()
            for idx, (_, kk) in enumerate(kps)
            if kk == k
        ]
        rec.add_point3D(np.asarray(xyz, dtype=np.float64), pycolmap.Track(elements), np.asarray(rgb, dtype=np.uint8))
    rec.update_point_3d_errors()
    assert rec.num_reg_images() == len(IMAGES), rec.num_reg_images()
    return rec


def distortion(model, params):
    if model == "SIMPLE_RADIAL":
        return [params[3], 0.0, 0.0, 0.0]
    if model == "RADIAL":
        return [params[3], params[4], 0.0, 0.0]
    if model == "OPENCV":
        return list(params[4:8])
    assert model == "PINHOLE", model
    return None


def calibration(model, params):
    if model in ("SIMPLE_RADIAL", "RADIAL"):
        f, cx, cy = params[:3]
        return np.array([[f, 0.0, cx], [0.0, f, cy], [0.0, 0.0, 1.0]])
    fx, fy, cx, cy = params[:4]
    return np.array([[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]])


def floats(a):
    return [float(x) for x in np.asarray(a, dtype=np.float64).ravel()]


def expected(rec):
    images = []
    for image in sorted(rec.images.values(), key=lambda im: im.name):
        cam = rec.cameras[image.camera_id]
        pose = image.cam_from_world()
        q = pose.rotation.quat  # x, y, z, w
        images.append(
            {
                "name": image.name,
                "image_id": int(image.image_id),
                "camera_id": int(image.camera_id),
                "model": cam.model.name,
                "width": int(cam.width),
                "height": int(cam.height),
                "params": floats(cam.params),
                "rotation": [floats(row) for row in pose.rotation.matrix()],
                "translation": floats(pose.translation),
                "quaternion_wxyz": floats([q[3], q[0], q[1], q[2]]),
                "center": floats(image.projection_center()),
                "num_points2D": int(image.num_points2D()),
                "num_points3D": int(image.num_points3D),
            }
        )
    cameras = []
    for camera_id in sorted(rec.cameras):
        cam = rec.cameras[camera_id]
        model, params = cam.model.name, floats(cam.params)
        dist = distortion(model, params)
        undistorted = None
        if dist is not None:
            new_k, roi = cv2.getOptimalNewCameraMatrix(
                calibration(model, params), np.asarray(dist, dtype=np.float64), (cam.width, cam.height), 0
            )
            undistorted = {
                "new_k": floats([new_k[0, 0], new_k[1, 1], new_k[0, 2], new_k[1, 2]]),
                "roi": [int(x) for x in roi],
            }
        cameras.append(
            {
                "camera_id": int(camera_id),
                "model": model,
                "width": int(cam.width),
                "height": int(cam.height),
                "params": params,
                "distortion": dist,
                "undistorted": undistorted,
            }
        )
    points = []
    for pid in sorted(rec.points3D):
        p = rec.points3D[pid]
        points.append(
            {
                "id": int(pid),
                "xyz": floats(p.xyz),
                "rgb": [int(c) for c in p.color],
                "error": float(p.error),
                "track": [[int(e.image_id), int(e.point2D_idx)] for e in p.track.elements],
            }
        )
    return {"pycolmap": pycolmap.__version__, "images": images, "cameras": cameras, "points3D": points}


def same(a, b):
    """The reconstructions read from text and binary agree (text keeps 17 significant digits)."""
    assert sorted(a.cameras) == sorted(b.cameras) and sorted(a.images) == sorted(b.images)
    assert sorted(a.points3D) == sorted(b.points3D)
    for i in a.cameras:
        ca, cb = a.cameras[i], b.cameras[i]
        assert (ca.model, ca.width, ca.height) == (cb.model, cb.width, cb.height)
        assert np.allclose(ca.params, cb.params, rtol=1e-15, atol=0)
    for i in a.images:
        ia, ib = a.images[i], b.images[i]
        assert ia.name == ib.name and ia.camera_id == ib.camera_id
        assert np.allclose(ia.cam_from_world().matrix(), ib.cam_from_world().matrix(), rtol=0, atol=1e-14)
        assert ia.num_points2D() == ib.num_points2D()
        for pa, pb in zip(ia.points2D, ib.points2D):
            assert np.allclose(pa.xy, pb.xy, rtol=0, atol=1e-13) and pa.point3D_id == pb.point3D_id
    for i in a.points3D:
        pa, pb = a.points3D[i], b.points3D[i]
        assert np.allclose(pa.xyz, pb.xyz, rtol=0, atol=1e-14) and (pa.color == pb.color).all()


def main():
    if OUT.exists():
        shutil.rmtree(OUT)
    text_dir, bin_dir, image_dir = OUT / "sparse/0", OUT / "sparse_bin/0", OUT / "images"
    for d in (text_dir, bin_dir, image_dir):
        d.mkdir(parents=True)

    rec = build()
    rec.write_text(str(text_dir))
    rec.write_binary(str(bin_dir))

    from_bin, from_text = pycolmap.Reconstruction(), pycolmap.Reconstruction()
    from_bin.read_binary(str(bin_dir))
    from_text.read_text(str(text_dir))
    same(from_bin, from_text)

    for seed, image in enumerate(sorted(from_bin.images.values(), key=lambda im: im.image_id)):
        cam = from_bin.cameras[image.camera_id]
        PILImage.fromarray(picture(cam.width, cam.height, seed)).save(image_dir / image.name, optimize=False)

    (OUT / "expected.json").write_text(json.dumps(expected(from_bin), indent=1) + "\n")
    total = sum(p.stat().st_size for p in OUT.rglob("*") if p.is_file())
    print(f"wrote {OUT} ({total} bytes)")
    assert total < 60_000, total


if __name__ == "__main__":
    main()
