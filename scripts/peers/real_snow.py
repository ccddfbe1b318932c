"""Blender's Real Snow add-on on one mesh, as a user runs it (the peer of `phenomena render
snow-cover`, issue 19). Run by Blender itself:

    blender -b --factory-startup --python-exit-code 1 --python scripts/peers/real_snow.py -- IN.obj OUT.obj

The work: import the OBJ (Blender's C++ importer, Y-up OBJ to Blender's Z-up), run the add-on
bundled with Blender (Debian `blender-data`: `scripts/addons/real_snow.py`, "Real Snow" 1.3 by
Marco Pavanello and Drew Perttula) with its default settings (coverage 100 %, height 0.3) on the
mesh — it deletes the faces turned down (more than 0.5 rad past horizontal), scatters metaball
"hair" particles over the rest (count ∝ area / height²), converts them to a mesh and adds a
decimate (0.5) and a subdivision modifier — then export the snow mesh with its modifiers applied
with Blender's C++ OBJ exporter (the fastest writer Blender has; ours writes GLB). Seeds Python's
`random` so the add-on's particle seed is the same every run.

What ours does besides (so the comparison favours this peer): snow probability from 32 shadow
maps, 48 accumulation and stabilisation steps, a rendered `render.png` and three GLB files.
"""

import random
import sys
import time

import addon_utils
import bpy

argv = sys.argv[sys.argv.index("--") + 1:]
src, dst = argv[0], argv[1]
t0 = time.perf_counter()
random.seed(0)
addon_utils.enable("real_snow", default_set=True)
# The factory scene's cube, camera and light go.
bpy.ops.object.select_all(action="SELECT")
bpy.ops.object.delete()
bpy.ops.wm.obj_import(filepath=src)
t_import = time.perf_counter()
bpy.ops.object.select_all(action="DESELECT")
objs = [o for o in bpy.context.scene.objects if o.type == "MESH"]
for o in objs:
    o.select_set(True)
bpy.context.view_layer.objects.active = objs[0]
assert bpy.ops.snow.create() == {"FINISHED"}
t_snow = time.perf_counter()
bpy.ops.object.select_all(action="DESELECT")
snow = [o for o in bpy.data.collections["Snow"].objects]
for o in snow:
    o.select_set(True)
bpy.ops.wm.obj_export(filepath=dst, export_selected_objects=True, apply_modifiers=True,
                      export_materials=False)
t_end = time.perf_counter()
tris = sum(len(p.vertices) - 2 for o in snow for p in o.evaluated_get(
    bpy.context.evaluated_depsgraph_get()).data.polygons)
print(f"real_snow: import {t_import - t0:.3f} s, snow {t_snow - t_import:.3f} s, "
      f"export {t_end - t_snow:.3f} s; snow mesh ≈ {tris} triangles", flush=True)
