"""Load a pixie-gs frame sequence (DIR/frame_*.ply from `pixie simulate` or `pixie demo`) into
Blender as ONE animated point object, and optionally render a frame.

Run with Blender's own Python (tested with Blender 3.4.1, headless):

    blender --background --factory-startup --python scripts/blender_import_frames.py -- \
        FRAMES_DIR OUT.blend [--render FRAME OUT.png]

What it builds: a mesh whose vertices are the Gaussian centres of frame 0, with one shape key
per later frame (keyed so that Blender frame k+1 shows frame_k), a point-domain colour attribute
`Col` (the splat's base colour 0.5 + 0.2821·f_dc) and a `radius` attribute (the geometric-mean
std-dev), drawn by a geometry-nodes "Mesh to Points" modifier with an emissive material. This is
a point view of the splat, not Gaussian splatting: for true splats inside Blender use a 3DGS
add-on on the frames (see docs/render.md).
"""
import sys
from pathlib import Path

import bpy
import numpy as np

SH_C0 = 0.28209479177387814
PLY_TYPES = {"char": "i1", "uchar": "u1", "short": "i2", "ushort": "u2", "int": "i4", "uint": "u4",
             "float": "f4", "double": "f8", "int8": "i1", "uint8": "u1", "int16": "i2", "uint16": "u2",
             "int32": "i4", "uint32": "u4", "float32": "f4", "float64": "f8"}


def read_vertices(path: Path) -> np.ndarray:
    """The vertex element of a binary little-endian PLY as a numpy structured array."""
    with open(path, "rb") as fh:
        if fh.readline().strip() != b"ply":
            raise SystemExit(f"{path}: not a PLY file")
        fields, count, fmt, in_vertex = [], 0, "", False
        while True:
            words = fh.readline().decode("ascii").split()
            if not words:
                continue
            if words[0] == "end_header":
                break
            if words[0] == "format":
                fmt = words[1]
            elif words[0] == "element":
                in_vertex = words[1] == "vertex"
                if in_vertex:
                    count = int(words[2])
                elif count:
                    break  # elements after the vertices are not needed
            elif words[0] == "property" and in_vertex:
                fields.append((words[2], "<" + PLY_TYPES[words[1]]))
        if fmt != "binary_little_endian":
            raise SystemExit(f"{path}: only binary_little_endian PLY is read here (pixie-gs writes it)")
        return np.fromfile(fh, dtype=np.dtype(fields), count=count)


def build(frames_dir: Path):
    files = sorted(frames_dir.glob("frame_*.ply"))
    if not files:
        raise SystemExit(f"{frames_dir}: no frame_*.ply files")
    v0 = read_vertices(files[0])
    n = len(v0)
    xyz = np.stack([v0["x"], v0["y"], v0["z"]], axis=1).astype(np.float32)
    mesh = bpy.data.meshes.new("splat")
    mesh.vertices.add(n)
    mesh.vertices.foreach_set("co", xyz.ravel())
    rgb = np.clip(0.5 + SH_C0 * np.stack([v0["f_dc_0"], v0["f_dc_1"], v0["f_dc_2"]], axis=1), 0, 1)
    col = mesh.attributes.new("Col", "FLOAT_COLOR", "POINT")
    col.data.foreach_set("color", np.concatenate([rgb, np.ones((n, 1))], axis=1).astype(np.float32).ravel())
    sigma = np.exp(np.mean(np.stack([v0["scale_0"], v0["scale_1"], v0["scale_2"]], axis=1), axis=1))
    rad = mesh.attributes.new("radius", "FLOAT", "POINT")
    rad.data.foreach_set("value", (1.5 * sigma).astype(np.float32))
    obj = bpy.data.objects.new("splat", mesh)
    bpy.context.scene.collection.objects.link(obj)

    obj.shape_key_add(name="frame_00000")
    for k, path in enumerate(files[1:], start=1):
        v = read_vertices(path)
        if len(v) != n:
            raise SystemExit(f"{path}: {len(v)} Gaussians, frame 0 has {n}")
        key = obj.shape_key_add(name=path.stem, from_mix=False)
        key.data.foreach_set("co", np.stack([v["x"], v["y"], v["z"]], axis=1).astype(np.float32).ravel())
        for frame, value in ((k, 0.0), (k + 1, 1.0), (k + 2, 0.0)):  # Blender frame k+1 shows frame_k
            key.value = value
            key.keyframe_insert("value", frame=frame)
        for fc in mesh.shape_keys.animation_data.action.fcurves:
            for point in fc.keyframe_points:
                point.interpolation = "CONSTANT"
    scene = bpy.context.scene
    scene.frame_start, scene.frame_end = 1, len(files)

    # points drawn with their colour: Mesh to Points (radius attribute) → Set Material
    mat = bpy.data.materials.new("splat_colour")
    mat.use_nodes = True
    nodes, links = mat.node_tree.nodes, mat.node_tree.links
    nodes.clear()
    attr = nodes.new("ShaderNodeAttribute")
    attr.attribute_name = "Col"
    emit = nodes.new("ShaderNodeEmission")
    out = nodes.new("ShaderNodeOutputMaterial")
    links.new(attr.outputs["Color"], emit.inputs["Color"])
    links.new(emit.outputs["Emission"], out.inputs["Surface"])
    tree = bpy.data.node_groups.new("splat_points", "GeometryNodeTree")
    tree.inputs.new("NodeSocketGeometry", "Geometry")
    tree.outputs.new("NodeSocketGeometry", "Geometry")
    gin, gout = tree.nodes.new("NodeGroupInput"), tree.nodes.new("NodeGroupOutput")
    to_points = tree.nodes.new("GeometryNodeMeshToPoints")
    radius = tree.nodes.new("GeometryNodeInputNamedAttribute")
    radius.data_type = "FLOAT"
    radius.inputs["Name"].default_value = "radius"
    set_mat = tree.nodes.new("GeometryNodeSetMaterial")
    set_mat.inputs["Material"].default_value = mat
    tree.links.new(gin.outputs["Geometry"], to_points.inputs["Mesh"])
    tree.links.new(radius.outputs["Attribute"], to_points.inputs["Radius"])
    tree.links.new(to_points.outputs["Points"], set_mat.inputs["Geometry"])
    tree.links.new(set_mat.outputs["Geometry"], gout.inputs["Geometry"])
    obj.modifiers.new("points", "NODES").node_group = tree
    return obj, files, xyz


def add_camera(xyz: np.ndarray) -> None:
    """A camera looking at the object's centre from −y, slightly above (z up), and a white world."""
    centre = (xyz.min(axis=0) + xyz.max(axis=0)) / 2
    size = float(np.max(xyz.max(axis=0) - xyz.min(axis=0)))
    cam = bpy.data.objects.new("camera", bpy.data.cameras.new("camera"))
    bpy.context.scene.collection.objects.link(cam)
    cam.location = (centre[0], centre[1] - 2.2 * size, centre[2] + 0.4 * size)
    direction = centre - np.array(cam.location)
    import mathutils

    cam.rotation_euler = mathutils.Vector(direction).to_track_quat("-Z", "Y").to_euler()
    bpy.context.scene.camera = cam
    world = bpy.data.worlds.new("world")
    world.color = (1, 1, 1)
    bpy.context.scene.world = world


def main(argv: list[str]) -> None:
    if len(argv) not in (2, 5) or (len(argv) == 5 and argv[2] != "--render"):
        raise SystemExit("usage: blender -b -P blender_import_frames.py -- FRAMES_DIR OUT.blend [--render FRAME OUT.png]")
    bpy.ops.wm.read_factory_settings(use_empty=True)  # no default cube, light or camera
    obj, files, xyz = build(Path(argv[0]))
    add_camera(xyz)
    bpy.ops.wm.save_as_mainfile(filepath=str(Path(argv[1]).resolve()))
    print(f"blender_import_frames: {len(files)} frames x {len(xyz)} Gaussians -> {argv[1]}")
    if len(argv) == 5:
        scene = bpy.context.scene
        scene.frame_set(int(argv[3]))
        scene.render.engine = "CYCLES"
        scene.cycles.samples = 16
        scene.cycles.use_denoising = False  # distribution builds may lack OpenImageDenoise
        scene.cycles.device = "CPU"
        scene.render.resolution_x = scene.render.resolution_y = 320
        scene.render.filepath = str(Path(argv[4]).resolve())
        bpy.ops.render.render(write_still=True)
        print(f"blender_import_frames: rendered frame {argv[3]} -> {argv[4]}")


if __name__ == "__main__":
    main(sys.argv[sys.argv.index("--") + 1:] if "--" in sys.argv else [])
