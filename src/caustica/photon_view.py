"""Pictures of where photons and streams land: records projected into the camera view.

``caustica photons SCENE --method pm|spm`` traces the maps exactly as a render
would and splats every stored record's power into the pixel it projects to
(records hidden from the camera are left out; null surfaces hide nothing).
In a scene with media only the surface records are drawn, not the volume photons.  Two panels side by side:

* pm: the global map | the caustic map (empty without --caustic-photons);
* spm: the leading photons (stream records, their own power) | the associated photons.

Each panel is normalised by its own 99th percentile (then sRGB-encoded), so the
*distribution* of power is visible; the picture says nothing about absolute units.
"""
from __future__ import annotations

import numpy as np

from .geometry import vec
from .geometry.scene_geometry import intersect, surface_at
from .jit import kernel
from .media import NULL_CROSSINGS_CAP
from .scene.description import NULL


@kernel
def seen(geom, mats, o, p):
    """Whether the point p is seen from o: nothing but null surfaces (a medium's invisible boundary) between."""
    for _ in range(NULL_CROSSINGS_CAP):
        rel = vec.sub(p, o)
        dist = vec.length(rel)
        if not dist > 0.0:
            return True
        d = vec.mul(rel, 1.0 / dist)
        prim, t, b1, b2 = intersect(geom, o, d, dist * (1.0 - 1e-4))
        if prim < 0:
            return True
        if mats.kind[geom.prim_material[prim]] != NULL:
            return False
        q, ng, _ = surface_at(geom, prim, o, d, t, b1, b2)
        o = vec.offset_origin(q, ng, d)
    return False


@kernel
def splat_records(geom, mats, cam, position, power, image):
    """Add each record's power to the pixel it projects to, if the camera sees it (past null surfaces)."""
    b = cam.basis
    o = (cam.origin[0], cam.origin[1], cam.origin[2])
    for i in range(position.shape[0]):
        p = (float(position[i, 0]), float(position[i, 1]), float(position[i, 2]))
        rel = vec.sub(p, o)
        if cam.orthographic:   # camera space through the inverse (to_world scales an orthographic view)
            ib = cam.inv_basis
            vx = ib[0, 0] * rel[0] + ib[0, 1] * rel[1] + ib[0, 2] * rel[2]
            vy = ib[1, 0] * rel[0] + ib[1, 1] * rel[1] + ib[1, 2] * rel[2]
            vz = ib[2, 0] * rel[0] + ib[2, 1] * rel[1] + ib[2, 2] * rel[2]
            if vz <= cam.near_clip:
                continue
            sx = 0.5 * (1.0 - vx / cam.tan_half_x)
            sy = 0.5 * (1.0 - vy / cam.tan_half_y)
            eye = (o[0] + b[0, 0] * vx + b[0, 1] * vy + b[0, 2] * cam.near_clip,   # where its ray starts
                   o[1] + b[1, 0] * vx + b[1, 1] * vy + b[1, 2] * cam.near_clip,
                   o[2] + b[2, 0] * vx + b[2, 1] * vy + b[2, 2] * cam.near_clip)
        else:
            vx = b[0, 0] * rel[0] + b[1, 0] * rel[1] + b[2, 0] * rel[2]
            vy = b[0, 1] * rel[0] + b[1, 1] * rel[1] + b[2, 1] * rel[2]
            vz = b[0, 2] * rel[0] + b[1, 2] * rel[1] + b[2, 2] * rel[2]
            if vz <= 0.0:
                continue
            sx = 0.5 * (1.0 - vx / (vz * cam.tan_half_x))
            sy = 0.5 * (1.0 - vy / (vz * cam.tan_half_y))
            eye = o
        if sx < 0.0 or sx >= 1.0 or sy < 0.0 or sy >= 1.0:
            continue
        if not seen(geom, mats, eye, p):
            continue
        px = int(sx * cam.width)
        py = int(sy * cam.height)
        for c in range(3):
            image[py, px, c] += power[i, c]


def _panel(scene, cam, position, power) -> np.ndarray:
    img = np.zeros((cam.height, cam.width, 3), np.float64)
    if position.shape[0]:
        splat_records(scene.geometry, scene.materials, cam, np.ascontiguousarray(position),
                      np.ascontiguousarray(power), img)
    lum = img.sum(axis=2)
    nz = lum[lum > 0]
    if nz.size:
        img /= np.percentile(nz, 99) / 3.0
    return np.clip(img, 0.0, 1.0)


def photon_picture(scene, method, settings, progress) -> tuple[np.ndarray, dict]:
    """Two panels (H x (2W + 2) x 3, linear values in [0, 1]) and the method's map statistics."""
    cam = scene.camera(settings.width, settings.height)
    scene = method.path_scene(scene, settings)   # the photons the render traces
    if method.name == "spm":
        smap, stats = method.build_stream_map(scene, settings, progress)
        left = _panel(scene, cam, smap.records.position, smap.lead_power)
        right = _panel(scene, cam, smap.assoc_pos, smap.associated_power())
        stats["panels"] = ["leading photons (stream records)", "associated photons"]
    else:
        gmap, cmap, _, stats = method.build_maps(scene, settings, progress)
        left = _panel(scene, cam, gmap.position, gmap.power)
        right = _panel(scene, cam, cmap.position, cmap.power)
        stats["panels"] = ["global map", "caustic map"]
    sep = np.full((cam.height, 2, 3), 0.5)
    return np.concatenate([left, sep, right], axis=1), stats
