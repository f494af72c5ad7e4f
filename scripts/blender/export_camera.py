"""Export the scene camera of a .blend file as a reframe camera file (JSON).

    blender scene.blend --background --python scripts/blender/export_camera.py -- out.json [--axes y-up|z-up]

Axes: Blender's world is Z-up; its OBJ exporter writes Y-up by default (Forward -Z, Up Y:
Blender's (x, y, z) becomes (x, z, -y)), and reframe's environment map is Y-up too. `--axes y-up`
(the default) turns the camera the same way, so that it lines up with an OBJ exported with those
defaults; `--axes z-up` keeps Blender's axes, for an OBJ exported with Up Z, Forward Y.

Writes one entry per frame from the scene's frame_start to frame_end (every frame_step-th),
renumbered from 0:

    {"frames": [
    {"frame": 0, "fov": 39.6, "matrix": [16 numbers]},
    ...]}

"matrix" is the camera's matrix_world (in the axes above), row-major: camera to world, the camera looking down its
-Z with +Y up, translation in the last column, the convention reframe reads (a scale on the
camera object is harmless: reframe uses only rotation and translation). "fov" is the vertical
field of view in degrees at the scene's render aspect, from the lens, the sensor and its fit
(reframe has no lens shift, no orthographic or panoramic camera). Then prints the lines to put
in the scene TOML: with a world lit by a lat-long image (an Environment Texture), its
[environment] lines too, turned as Blender shows the sky (`rotation = 90` for its default
mapping; see environment_lines). See the README, "Scenes", and docs/camera.md.
"""
import json
import math
import os
import sys

import bpy


def vertical_fov(render, cam):
    """Vertical field of view in degrees, as Blender frames the render (Camera > Sensor Fit)."""
    w = render.resolution_x * render.pixel_aspect_x
    h = render.resolution_y * render.pixel_aspect_y
    fit = cam.sensor_fit
    if fit == "AUTO":
        # Auto: the sensor width spans the longer side of the image.
        fit, size = ("HORIZONTAL" if w >= h else "VERTICAL"), cam.sensor_width
    else:
        size = cam.sensor_width if fit == "HORIZONTAL" else cam.sensor_height
    tan_half = size / (2.0 * cam.lens)
    if fit == "HORIZONTAL":
        tan_half *= h / w
    return math.degrees(2.0 * math.atan(tan_half))


# Blender's world (Z up) to the Y-up axes of its OBJ exporter's defaults (Forward -Z, Up Y):
# (x, y, z) -> (x, z, -y), applied to the camera-to-world matrix from the left.
Y_UP = ((1, 0, 0, 0), (0, 0, 1, 0), (0, -1, 0, 0), (0, 0, 0, 1))
USAGE = "usage: blender FILE.blend --background --python export_camera.py -- OUT.json [--axes y-up|z-up]"


def parse_args():
    argv = sys.argv[sys.argv.index("--") + 1 :] if "--" in sys.argv else []
    axes = "y-up"
    if "--axes" in argv:
        i = argv.index("--axes")
        if i + 1 >= len(argv) or argv[i + 1] not in ("y-up", "z-up"):
            sys.exit(f"export_camera: --axes takes y-up or z-up\n{USAGE}")
        axes = argv[i + 1]
        del argv[i : i + 2]
    if len(argv) != 1:
        sys.exit(USAGE)
    return argv[0], axes


def rows(m, axes):
    """The 4 x 4 camera-to-world matrix `m` as rows, in the output's axes."""
    m = [[m[r][c] for c in range(4)] for r in range(4)]
    if axes == "y-up":
        m = [[sum(Y_UP[r][k] * m[k][c] for k in range(4)) for c in range(4)] for r in range(4)]
    return m


def environment_lines(world, axes):
    """The scene TOML's [environment] lines for a world lit by a lat-long image, and notes.

    Cycles maps a direction d of Blender's world to the image's u = (atan2(d.y, d.x) - pi) /
    (-2 pi): the image's middle is Blender's +X, the OBJ's +X through the exporter's default
    axes. reframe's middle is +Z (docs/environment.md), and `rotation` turns the sky about +Y,
    +Z towards +X: 90 degrees lines the two up. A Mapping node in front of the texture turning
    the lookup by phi about Blender's Z (its Point and Vector types; Texture turns it by -phi)
    shows the sky turned by -phi about Z, which is -phi about the OBJ's +Y.
    """
    tree = getattr(world, "node_tree", None) if world is not None and getattr(world, "use_nodes", False) else None
    env = next((n for n in tree.nodes if n.type == "TEX_ENVIRONMENT"), None) if tree else None
    if env is None or env.image is None:
        return [], []
    notes = []
    if env.projection != "EQUIRECTANGULAR":
        notes.append(f"the world's Environment Texture is {env.projection}: reframe reads lat-long (equirectangular) images")
    rotation = 90.0
    links = env.inputs["Vector"].links
    mapping = links[0].from_node if links else None
    if mapping is not None and mapping.type == "MAPPING":
        rx, ry, rz = mapping.inputs["Rotation"].default_value
        if abs(rx) > 1e-6 or abs(ry) > 1e-6:
            notes.append("the world's Mapping node turns the sky about X or Y: reframe turns it about the vertical only, and that part is left out")
        phi = math.degrees(rz)
        rotation += phi if mapping.vector_type == "TEXTURE" else -phi
    elif mapping is not None:
        notes.append(f"the world's Environment Texture reads its vector from a {mapping.type} node, left out")
    if axes == "z-up":
        notes.append("with --axes z-up the sky would lie on its side (reframe's environment is Y-up): export the OBJ and the camera Y-up to light the scene by it")
    background = next((n for n in tree.nodes if n.type == "BACKGROUND"), None)
    strength = background.inputs["Strength"].default_value if background is not None else 1.0
    name = json.dumps(os.path.basename(bpy.path.abspath(env.image.filepath)), ensure_ascii=False)
    lines = ["[environment]", f"image = {name}  # copy the image beside the scene TOML"]
    lines.append(f"rotation = {round(rotation % 360.0, 6):g}  # Blender's world orientation")
    if strength != 1.0:
        lines.append(f"intensity = {strength:g}")
    return lines, notes


def main():
    out, axes = parse_args()
    scene = bpy.context.scene
    obj = scene.camera
    if obj is None:
        sys.exit(f"export_camera: scene '{scene.name}' has no active camera")
    render = scene.render
    entries = []
    for i, f in enumerate(range(scene.frame_start, scene.frame_end + 1, scene.frame_step)):
        scene.frame_set(f)
        # The evaluated camera: parents, constraints, drivers and animated lenses applied.
        cam = obj.evaluated_get(bpy.context.evaluated_depsgraph_get())
        if cam.data.type != "PERSP":
            sys.exit(f"export_camera: frame {f}: camera '{obj.name}' is {cam.data.type}, not PERSP")
        if cam.data.shift_x or cam.data.shift_y:
            print(f"export_camera: frame {f}: lens shift ignored (reframe has none)", file=sys.stderr)
        m = rows(cam.matrix_world, axes)
        entries.append(
            json.dumps(
                {
                    "frame": i,
                    "fov": vertical_fov(render, cam.data),
                    "matrix": [m[r][c] for r in range(4) for c in range(4)],
                },
                allow_nan=False,
            )
        )
    with open(out, "w") as fh:
        fh.write('{"frames": [\n' + ",\n".join(entries) + "\n]}\n")
    if render.pixel_aspect_x != render.pixel_aspect_y:
        print("export_camera: non-square pixels: reframe's are square", file=sys.stderr)
    pct = render.resolution_percentage / 100.0
    w, h = round(render.resolution_x * pct), round(render.resolution_y * pct)
    print(
        f"export_camera: wrote {len(entries)} frames to {out} ({axes}: export the OBJ with "
        + ("Up Y, Forward -Z, Blender's defaults" if axes == "y-up" else "Up Z, Forward Y")
        + "); in the scene TOML:"
    )
    # A TOML string, escaped as JSON escapes it (backslashes of a Windows path, quotes and
    # control characters; JSON's escapes are TOML's). The TOML reads the path relative to its
    # own folder: the name alone, for the camera file kept beside the scene.
    name = json.dumps(os.path.basename(out), ensure_ascii=False)
    print(f"frames = {len(entries)}\nresolution = [{w}, {h}]")
    print(f"camera = {name}  # read relative to the scene TOML's folder: keep the file beside it")
    lines, notes = environment_lines(getattr(scene, "world", None), axes)
    for n in notes:
        print(f"export_camera: {n}", file=sys.stderr)
    if lines:
        print("\n".join(lines))


main()
