"""Stages whose light touches are known by construction, for tests/test_suggest_truth.py.

Each builder writes a small USD stage (usda text, opened once with usd-core to check it)
into a folder and returns (stage path, truth function). The truth function gives, for an
image of (width, height) pixels, the (height, width) int64 label of what each pixel's
central camera ray sees by construction (-1: nothing of the construction, left out).

Every stage has one pinhole camera at (0, 0, CAMERA_Z) looking down -Z, focal length 35 mm,
horizontal aperture 36 mm and a vertical one of 36 · height / width (no fit to resolve),
a black background and no dome, so every path ends at one of the stage's lights.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

TEXTURE = Path(__file__).resolve().parents[1] / "render" / "textures" / "two_frequencies.png"
FOCAL, APERTURE = 35.0, 36.0


def camera_rays(width: int, height: int) -> tuple[np.ndarray, np.ndarray]:
    """(h, w) x and y slopes of each pixel's central ray (direction (x, y, -1)); rows from the top."""
    columns = ((np.arange(width) + 0.5) / width - 0.5) * APERTURE / FOCAL
    rows = (0.5 - (np.arange(height) + 0.5) / height) * APERTURE * height / width / FOCAL
    return np.broadcast_to(columns[None, :], (height, width)), np.broadcast_to(rows[:, None], (height, width))


def _header(camera_z: float, width: int, height: int) -> str:
    return f'''#usda 1.0
(
    defaultPrim = "World"
    metersPerUnit = 1
    upAxis = "Y"
)

def Xform "World"
{{
    def Camera "Camera"
    {{
        float2 clippingRange = (0.01, 100)
        float focalLength = {FOCAL}
        float horizontalAperture = {APERTURE}
        float verticalAperture = {APERTURE * height / width}
        double3 xformOp:translate = (0, 0, {camera_z})
        uniform token[] xformOpOrder = ["xformOp:translate"]
    }}
'''


def _quads(name: str, quads: list[list[tuple]], material: str) -> str:
    """A Mesh of quads (each 4 corners, metres), bound to /World/Materials/<material>."""
    points = [corner for quad in quads for corner in quad]
    text = ", ".join(f"({x}, {y}, {z})" for x, y, z in points)
    st = ", ".join("(0, 0), (1, 0), (1, 1), (0, 1)" for _ in quads)
    return f'''
    def Mesh "{name}" (prepend apiSchemas = ["MaterialBindingAPI"])
    {{
        uniform bool doubleSided = 1
        int[] faceVertexCounts = [{", ".join("4" for _ in quads)}]
        int[] faceVertexIndices = [{", ".join(str(i) for i in range(len(points)))}]
        point3f[] points = [{text}]
        texCoord2f[] primvars:st = [{st}] (interpolation = "faceVarying")
        uniform token subdivisionScheme = "none"
        rel material:binding = </World/Materials/{material}>
    }}
'''


def _material(name: str, diffuse=(0.7, 0.7, 0.7), *, mirror: bool = False, texture: Path | None = None) -> str:
    surface = f"/World/Materials/{name}/surface.outputs:surface"
    if mirror:
        inputs = ("color3f inputs:diffuseColor = (0, 0, 0)\n            float inputs:roughness = 0\n"
                  "            color3f inputs:specularColor = (0.95, 0.95, 0.95)\n")
    elif texture is not None:
        inputs = (f"color3f inputs:diffuseColor.connect = </World/Materials/{name}/image.outputs:rgb>\n"
                  "            float inputs:roughness = 1\n            color3f inputs:specularColor = (0, 0, 0)\n")
    else:
        inputs = (f"color3f inputs:diffuseColor = {tuple(diffuse)}\n            float inputs:roughness = 1\n"
                  "            color3f inputs:specularColor = (0, 0, 0)\n")
    text = f'''
        def Material "{name}"
        {{
            token outputs:surface.connect = <{surface}>
            def Shader "surface"
            {{
                uniform token info:id = "UsdPreviewSurface"
                {inputs.strip()}
                int inputs:useSpecularWorkflow = 1
                token outputs:surface
            }}
'''
    if texture is not None:
        text += f'''
            def Shader "st"
            {{
                uniform token info:id = "UsdPrimvarReader_float2"
                string inputs:varname = "st"
                float2 outputs:result
            }}
            def Shader "image"
            {{
                uniform token info:id = "UsdUVTexture"
                asset inputs:file = @{texture}@
                token inputs:sourceColorSpace = "raw"
                float2 inputs:st.connect = </World/Materials/{name}/st.outputs:result>
                float3 outputs:rgb
            }}
'''
    return text + "        }\n"


def _light(name: str, position, color, intensity: float, radius: float, linked: tuple[str, ...] = (),
           group: str = "") -> str:
    """A SphereLight /World/<name>; linked : prims under /World it lights alone; group : its
    pxrLayers:lightGroup ("" none)."""
    link = ""
    if linked:
        targets = ", ".join(f"</World/{prim}>" for prim in linked)
        link = (f"uniform bool collection:lightLink:includeRoot = 0\n"
                f"        rel collection:lightLink:includes = [{targets}]\n")
    if group:
        link += f'uniform string pxrLayers:lightGroup = "{group}"\n        '
    return f'''
    def SphereLight "{name}"
    {{
        {link}color3f inputs:color = {tuple(color)}
        float inputs:intensity = {intensity}
        bool inputs:normalize = 0
        float inputs:radius = {radius}
        double3 xformOp:translate = {tuple(position)}
        uniform token[] xformOpOrder = ["xformOp:translate"]
    }}
'''


def _write(folder: Path, name: str, body: str, materials: str, width: int, height: int, camera_z: float) -> Path:
    import pxr_layers.stage  # noqa: F401  registers the pxrLayers schema before this process opens a stage
    from pxr import Usd

    stage = Path(folder) / f"{name}.usda"
    stage.write_text(_header(camera_z, width, height) + body + '\n    def Scope "Materials"\n    {' + materials
                     + "    }\n}\n")
    assert Usd.Stage.Open(str(stage)), stage
    return stage


CELL_X = (-1.1, 0.0, 1.1)
CELL_LIGHTS = (("red", (1.0, 0.08, 0.05)), ("green", (0.08, 1.0, 0.1)), ("blue", (0.1, 0.2, 1.0)))


def compartments(folder: Path, width: int = 96, height: int = 48):
    """(a) Three boxes side by side (1 m wide and tall, 1.5 m deep, open toward the camera at
    z = 0 but for a lip along its top that hides the light from the camera), each with its
    own walls (/World/walls_<colour>), a ball (/World/ball_<colour>) and
    a coloured SphereLight (/World/<colour>) inside, light-linked to its own box only: every
    path touches exactly one light, one set of walls and one ball. Truth: the box (0, 1, 2)
    whose opening the pixel's central ray passes through."""
    camera_z = 3.4
    body, materials = "", _material("white") + _material("grey", (0.5, 0.5, 0.5))
    for cx, (colour, rgb) in zip(CELL_X, CELL_LIGHTS):
        x0, x1 = cx - 0.5, cx + 0.5
        back = [(x0, -0.5, -1.5), (x1, -0.5, -1.5), (x1, 0.5, -1.5), (x0, 0.5, -1.5)]
        floor = [(x0, -0.5, 0), (x1, -0.5, 0), (x1, -0.5, -1.5), (x0, -0.5, -1.5)]
        ceiling = [(x0, 0.5, -1.5), (x1, 0.5, -1.5), (x1, 0.5, 0), (x0, 0.5, 0)]
        left = [(x0, -0.5, 0), (x0, -0.5, -1.5), (x0, 0.5, -1.5), (x0, 0.5, 0)]
        right = [(x1, -0.5, -1.5), (x1, -0.5, 0), (x1, 0.5, 0), (x1, 0.5, -1.5)]
        lip = [(x0, 0.25, 0), (x1, 0.25, 0), (x1, 0.5, 0), (x0, 0.5, 0)]  # hides the light from the camera
        body += _quads(f"walls_{colour}", [back, floor, ceiling, left, right, lip], "white")
        body += f'''
    def Sphere "ball_{colour}" (prepend apiSchemas = ["MaterialBindingAPI"])
    {{
        double radius = 0.25
        float3[] extent = [(-0.25, -0.25, -0.25), (0.25, 0.25, 0.25)]
        rel material:binding = </World/Materials/grey>
        double3 xformOp:translate = ({cx}, -0.25, -0.9)
        uniform token[] xformOpOrder = ["xformOp:translate"]
    }}
'''
        body += _light(colour, (cx, 0.42, -0.12), rgb, 30.0, 0.05, (f"walls_{colour}", f"ball_{colour}"))
    stage = _write(folder, "compartments", body, materials, width, height, camera_z)

    def truth(w: int, h: int) -> np.ndarray:
        sx, sy = camera_rays(w, h)
        x, y = sx * camera_z, sy * camera_z  # where the ray crosses z = 0
        label = np.full((h, w), -1, np.int64)
        for number, cx in enumerate(CELL_X):
            label[(np.abs(x - cx) < 0.5) & (np.abs(y) < 0.5)] = number
        return label

    return stage, truth


def mirror(folder: Path, width: int = 64, height: int = 64):
    """(b) One light (/World/lamp) lighting a diffuse wall (/World/wall, left half, facing
    the camera) directly, and a diffuse screen behind the camera (/World/screen) that the
    camera sees only through a mirror (/World/mirror, right half). Truth: 0 where the central
    ray hits the wall, 1 where it hits the mirror."""
    camera_z = 3.0
    wall = [(-1.6, -1.6, -1.0), (-0.02, -1.6, -1.0), (-0.02, 1.6, -1.0), (-1.6, 1.6, -1.0)]
    glass = [(0.02, -1.6, -1.0), (1.6, -1.6, -1.0), (1.6, 1.6, -1.0), (0.02, 1.6, -1.0)]
    screen = [(-6, -6, 5.0), (-6, 6, 5.0), (6, 6, 5.0), (6, -6, 5.0)]
    body = (_quads("wall", [wall], "white") + _quads("mirror", [glass], "chrome") + _quads("screen", [screen], "white")
            + _light("lamp", (0.0, 1.4, 1.0), (1.0, 0.9, 0.8), 400.0, 0.1))
    materials = _material("white") + _material("chrome", mirror=True)
    stage = _write(folder, "mirror", body, materials, width, height, camera_z)

    return stage, _halves(camera_z + 1.0, 1.6, 0.02, 1.6)  # where the rays cross z = -1


def textured(folder: Path, width: int = 64, height: int = 48):
    """(c) Two flat quads side by side facing the camera under one light (/World/lamp): a
    textured poster (/World/poster, two_frequencies.png) and a plain grey board (/World/board).
    Truth: 0 where the central ray hits the poster, 1 the board."""
    camera_z = 3.0
    left = [(-1.1, -0.5, 0.0), (-0.1, -0.5, 0.0), (-0.1, 0.5, 0.0), (-1.1, 0.5, 0.0)]
    right = [(0.1, -0.5, 0.0), (1.1, -0.5, 0.0), (1.1, 0.5, 0.0), (0.1, 0.5, 0.0)]
    body = (_quads("poster", [left], "printed") + _quads("board", [right], "grey")
            + _light("lamp", (0.0, 1.0, 1.5), (1.0, 1.0, 1.0), 200.0, 0.1))
    materials = _material("printed", texture=TEXTURE) + _material("grey", (0.5, 0.5, 0.5))
    stage = _write(folder, "textured", body, materials, width, height, camera_z)

    return stage, _halves(camera_z, 0.5, 0.1, 1.1)


def _halves(distance: float, half_height: float, gap: float, extent: float):
    """The truth of two panels side by side at `distance` (m) in front of the camera: 0 where
    the central ray crosses them at -extent < x < -gap, 1 at gap < x < extent, |y| < half_height;
    -1 elsewhere. Returns truth(w, h) -> (h, w) int64."""
    def truth(w: int, h: int) -> np.ndarray:
        sx, sy = camera_rays(w, h)
        x, y = sx * distance, sy * distance
        label = np.full((h, w), -1, np.int64)
        inside = np.abs(y) < half_height
        label[inside & (x > -extent) & (x < -gap)] = 0
        label[inside & (x > gap) & (x < extent)] = 1
        return label

    return truth


def _board(x0: float, x1: float, y0: float, y1: float) -> list[tuple]:
    """A quad in the plane z = 0 facing the camera (+Z), metres."""
    return [(x0, y0, 0.0), (x1, y0, 0.0), (x1, y1, 0.0), (x0, y1, 0.0)]


def _inside(w: int, h: int, camera_z: float, x0: float, x1: float, y0: float, y1: float) -> np.ndarray:
    sx, sy = camera_rays(w, h)
    x, y = sx * camera_z, sy * camera_z  # where the central ray crosses z = 0
    return (x > x0) & (x < x1) & (y > y0) & (y < y1)


GROUP_BOARDS = {"rim_top": (-1.5, -0.7, 0.05, 0.6), "rim_bottom": (-1.5, -0.7, -0.6, -0.05),
                "key_board": (-0.4, 1.5, -0.6, 0.6)}
"""name → (x0, x1, y0, y1) of each board of the light groups stage, metres at z = 0."""


def light_groups(folder: Path, width: int = 96, height: int = 48):
    """(d) Three grey boards facing the camera, in the plane z = 0, no light seen by the
    camera: on the left two small boards one above the other (/World/rim_top, /World/rim_bottom),
    each lit alone by one light of group "rim" (/World/rim_a, /World/rim_b: light-linked), on the
    right a large board (/World/key_board) lit alone by /World/key of group "front". Coplanar
    boards do not light each other: every path is camera, board, light. Truth: 0 where the
    central ray hits a rim board (the rim group's part), 1 the key's board."""
    camera_z = 3.4
    body = "".join(_quads(name, [_board(*corners)], "grey") for name, corners in GROUP_BOARDS.items())
    body += (_light("rim_a", (-1.1, 1.4, 1.0), (1, 1, 1), 60.0, 0.05, ("rim_top",), "rim")
             + _light("rim_b", (-1.1, -1.4, 1.0), (1, 1, 1), 60.0, 0.05, ("rim_bottom",), "rim")
             + _light("key", (0.55, 1.4, 1.5), (1, 1, 1), 200.0, 0.05, ("key_board",), "front"))
    stage = _write(folder, "light_groups", body, _material("grey", (0.5, 0.5, 0.5)), width, height, camera_z)

    def truth(w: int, h: int) -> np.ndarray:
        label = np.full((h, w), -1, np.int64)
        for name, corners in GROUP_BOARDS.items():
            label[_inside(w, h, camera_z, *corners)] = 1 if name == "key_board" else 0
        return label

    return stage, truth


ASSET_BOARDS = {"chair": {"seat": (-1.5, -0.1, -0.6, -0.05), "back": (-1.5, -0.1, 0.05, 0.6)},
                "table": {"top": (0.1, 1.5, 0.05, 0.6), "leg": (0.1, 1.5, -0.6, -0.05)}}
"""model → its two meshes → (x0, x1, y0, y1), metres at z = 0."""


def assets(folder: Path, width: int = 96, height: int = 48):
    """(e) Two component models (/World/chair: seat and back; /World/table: top and leg, each
    mesh its own quad facing the camera in the plane z = 0, all of one grey material) under one
    lamp behind the camera (/World/lamp), which lights the four alike. Truth: 0 where the central ray hits the chair, 1 the table."""
    camera_z = 3.4
    body = ""
    for model, meshes in ASSET_BOARDS.items():
        parts = "".join(_quads(name, [_board(*corners)], "grey") for name, corners in meshes.items())
        body += f'''
    def Xform "{model}" (kind = "component")
    {{{parts}    }}
'''
    body += _light("lamp", (0.0, 0.0, 8.0), (1, 1, 1), 4000.0, 0.05)  # behind the camera: every mesh alike
    stage = _write(folder, "assets", body, _material("grey", (0.5, 0.5, 0.5)), width, height, camera_z)

    def truth(w: int, h: int) -> np.ndarray:
        label = np.full((h, w), -1, np.int64)
        for number, meshes in enumerate(ASSET_BOARDS.values()):
            for corners in meshes.values():
                label[_inside(w, h, camera_z, *corners)] = number
        return label

    return stage, truth
