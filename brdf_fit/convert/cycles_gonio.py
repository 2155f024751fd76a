"""A gonioreflectometer in Blender's Cycles: run inside Blender's Python (``bpy``), it renders
flat quads of one material under a sun and returns ``f(wi, wo) cos(theta_i)`` per quad.

This file imports nothing from ``brdf_fit`` (Blender's Python has its own NumPy and no JAX):
:func:`brdf_fit.convert.blender.measure_in_cycles` writes a job, runs this file with the Blender
Python it finds, and reads the answer. Run by hand::

    python-with-bpy cycles_gonio.py job.json         # or: blender -b -P cycles_gonio.py -- job.json

The job (JSON): ``script`` (a material script written by :mod:`brdf_fit.convert.blender`),
``material`` (its name), ``renders``: a list of ``{"gamma": g, "quads": [{"n": [3], "t": [3]},
...]}`` and ``out`` (where the answer goes). The scene of one render:

* an orthographic camera looking down ``-z`` (the view direction ``wo = (0, 0, 1)`` in world
  space at every pixel);
* a sun of strength 1 (irradiance 1 W/m^2 on a surface facing it), angle 0, arriving from
  ``(sin g, 0, cos g)``: Cycles' sun strength is irradiance, so a pixel's value is
  ``f cos(theta_i)``;
* one flat quad per pair, normal ``n`` and UV tangent ``t`` (world space), in its own cell of a
  grid, sloped so that its image fills the cell whatever ``n`` (down to ``n.z = 1e-3``), with UV
  coordinates along ``t`` and ``n x t`` (a Tangent node on the UV map then gives ``t``); no quad
  casts a shadow (``visible_shadow`` off), none is in another's cell;
* direct light only (no bounces), one sample per pixel, no denoising; the world is black.

Every pixel of a cell sees the same ``(wi, wo)`` in the quad's frame, so the answer is the mean of
the cell's central 2 x 2 pixels (their spread is reported: 0 where Cycles is deterministic). The
image is written as 32-bit OpenEXR (scene linear) and read back with Blender's image loader.
"""

from __future__ import annotations

import json
import math
import sys
import time

#: pixels per cell side (the central 2 x 2 are read, 3 pixels from the cell's edges, beyond
#: Cycles' default 1.5-pixel pixel filter)
CELL_PIXELS = 8
#: the camera's height above the grid (the sloped quads reach at most about CELL / (2 n.z))
CAMERA_HEIGHT = 5000.0


def _scene(bpy):
    bpy.ops.wm.read_factory_settings(use_empty=True)
    sc = bpy.context.scene
    sc.render.engine = "CYCLES"
    cy = sc.cycles
    cy.device = "CPU"
    cy.samples = 1
    cy.use_adaptive_sampling = False
    cy.use_denoising = False
    cy.max_bounces = 0
    cy.seed = 0
    sc.render.resolution_percentage = 100
    sc.render.image_settings.file_format = "OPEN_EXR"
    sc.render.image_settings.color_depth = "32"
    sc.view_settings.view_transform = "Standard"
    world = bpy.data.worlds.new("black")
    world.use_nodes = True
    world.node_tree.nodes["Background"].inputs[1].default_value = 0.0
    sc.world = world
    cam = bpy.data.cameras.new("gonio_camera")
    cam.type = "ORTHO"
    cam.clip_start = 1.0
    cam.clip_end = 4.0 * CAMERA_HEIGHT
    cam_ob = bpy.data.objects.new("gonio_camera", cam)
    sc.collection.objects.link(cam_ob)
    sc.camera = cam_ob
    cam_ob.location = (0.0, 0.0, CAMERA_HEIGHT)
    sun = bpy.data.lights.new("gonio_sun", "SUN")
    sun.energy = 1.0
    sun.angle = 0.0
    sun_ob = bpy.data.objects.new("gonio_sun", sun)
    sc.collection.objects.link(sun_ob)
    return sc, cam, sun_ob


def _cross(a, b):
    return (a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0])


def _quad(bpy, sc, material, k, cx, cy, n, t):
    """A quad whose image is the unit cell centred at ``(cx, cy)``, in the plane of normal ``n``
    through ``(cx, cy, 0)``, UVs along ``t`` and ``n x t``."""
    b = _cross(n, t)
    verts, uvs = [], []
    for dx, dy in ((-0.5, -0.5), (0.5, -0.5), (0.5, 0.5), (-0.5, 0.5)):
        dz = -(n[0] * dx + n[1] * dy) / n[2]
        verts.append((cx + dx, cy + dy, dz))
        uvs.append((dx * t[0] + dy * t[1] + dz * t[2], dx * b[0] + dy * b[1] + dz * b[2]))
    me = bpy.data.meshes.new(f"gonio_quad_{k}")
    me.from_pydata(verts, [], [(0, 1, 2, 3)])
    uv = me.uv_layers.new(name="UVMap")
    for loop in me.loops:
        uv.data[loop.index].uv = uvs[loop.vertex_index]
    me.materials.append(material)
    ob = bpy.data.objects.new(f"gonio_quad_{k}", me)
    ob.visible_shadow = False
    sc.collection.objects.link(ob)
    return ob


def run(job: dict) -> dict:
    import bpy  # noqa: PLC0415 (Blender's module, only inside Blender's Python)
    import numpy as np  # noqa: PLC0415

    started = time.perf_counter()
    sc, cam, sun_ob = _scene(bpy)
    with open(job["script"], encoding="utf-8") as fh:
        code = compile(fh.read(), job["script"], "exec")
    exec(code, {"__name__": "__brdf_fit_material__"})  # the export script makes the material
    material = bpy.data.materials[job["material"]]
    values, spreads = [], []
    exr = job["out"] + ".exr"
    for render in job["renders"]:
        quads = render["quads"]
        cols = max(1, math.ceil(math.sqrt(len(quads))))
        rows = math.ceil(len(quads) / cols)
        sc.render.resolution_x = cols * CELL_PIXELS
        sc.render.resolution_y = rows * CELL_PIXELS
        cam.ortho_scale = float(max(cols, rows))
        g = float(render["gamma"])
        sun_ob.rotation_euler = (0.0, g, 0.0)  # the sun's +z (toward the light) = (sin g, 0, cos g)
        objects = []
        for k, q in enumerate(quads):
            col, row = k % cols, k // cols
            cx, cy = col + 0.5 - cols / 2.0, row + 0.5 - rows / 2.0
            objects.append(_quad(bpy, sc, material, k, cx, cy, q["n"], q["t"]))
        sc.render.filepath = exr
        bpy.ops.render.render(write_still=True)
        img = bpy.data.images.load(exr)
        px = np.array(img.pixels[:], dtype=np.float64).reshape(
            sc.render.resolution_y, sc.render.resolution_x, 4)
        bpy.data.images.remove(img)
        c0 = CELL_PIXELS // 2 - 1
        for k in range(len(quads)):
            col, row = k % cols, k // cols
            cell = px[row * CELL_PIXELS + c0: row * CELL_PIXELS + c0 + 2,
                      col * CELL_PIXELS + c0: col * CELL_PIXELS + c0 + 2, :3].reshape(-1, 3)
            values.append(cell.mean(axis=0).tolist())
            spreads.append(float(np.max(cell.max(axis=0) - cell.min(axis=0))))
        for ob in objects:
            mesh = ob.data
            bpy.data.objects.remove(ob)
            bpy.data.meshes.remove(mesh)
    return {"values": values, "spread": spreads, "blender": bpy.app.version_string,
            "seconds": time.perf_counter() - started}


def main(argv) -> int:
    args = argv[argv.index("--") + 1:] if "--" in argv else argv[1:]
    if len(args) != 1:
        print("usage: cycles_gonio.py JOB.json", file=sys.stderr)
        return 2
    with open(args[0], encoding="utf-8") as fh:
        job = json.load(fh)
    answer = run(job)
    with open(job["out"], "w", encoding="utf-8") as fh:
        json.dump(answer, fh)
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv))
