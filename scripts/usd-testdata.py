#!/usr/bin/env python3
"""Writes the USD test stages of scene/tests/data/usd/ with Pixar's usd-core (test data only:
lightfold reads USD with its own Rust loader, never through this).

    python3 -m venv /tmp/usd && /tmp/usd/bin/pip install usd-core
    /tmp/usd/bin/python scripts/usd-testdata.py            # rewrites scene/tests/data/usd/

lights.usda holds one light of each supported UsdLux type (rect, disk, sphere, a sphere
treated as a point, the same with a cone as a spot, cylinder, distant with an angle) over a ground plane with an
occluder box, under composed transforms; lights.toml beside it is the same scene written by
hand. lights.usdc and lights.usdz are the same stage in the binary and package forms.
"""

import os
import sys

from pxr import Gf, Sdf, Usd, UsdGeom, UsdLux, UsdShade, UsdUtils

ROOT = os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "scene", "tests", "data", "usd")


def plane_points(half):
    # The corner order of lightfold's plane primitive (normal +Y, u along +X, v = n × u = -Z),
    # so the fan (0, 1, 2), (0, 2, 3) is its two triangles.
    return [(-half, 0, half), (half, 0, half), (half, 0, -half), (-half, 0, -half)]


def cuboid(half):
    """lightfold's box primitive: 24 points, each face a quad with its outward normal."""
    points, normals = [], []
    axes = [(1, 0, 0), (0, 1, 0), (0, 0, 1)]
    for a in range(3):
        for sign in (1, -1):
            n = Gf.Vec3f(*axes[a]) * sign
            u = Gf.Vec3f(*axes[(a + 1) % 3]) * sign
            v = Gf.Cross(n, u)
            c = n * half[a]
            hu, hv = half[(a + 1) % 3], half[(a + 2) % 3]
            for su, sv in ((-1, -1), (1, -1), (1, 1), (-1, 1)):
                points.append(c + u * (su * hu) + v * (sv * hv))
                normals.append(n)
    return points, normals


def mesh(stage, path, points, counts, indices, normals, color, double_sided):
    m = UsdGeom.Mesh.Define(stage, path)
    m.CreatePointsAttr(points)
    m.CreateFaceVertexCountsAttr(counts)
    m.CreateFaceVertexIndicesAttr(indices)
    m.CreateNormalsAttr(normals)
    m.SetNormalsInterpolation(UsdGeom.Tokens.vertex)
    m.CreateSubdivisionSchemeAttr(UsdGeom.Tokens.none)
    m.CreateDoubleSidedAttr(double_sided)
    m.CreateDisplayColorAttr([color])
    return m


def lights_stage(path):
    stage = Usd.Stage.CreateNew(path)
    UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.y)
    UsdGeom.SetStageMetersPerUnit(stage, 1.0)
    world = UsdGeom.Xform.Define(stage, "/World")
    stage.SetDefaultPrim(world.GetPrim())
    mesh(stage, "/World/Ground", plane_points(5.0), [4], [0, 1, 2, 3], [(0, 1, 0)] * 4,
         (0.8, 0.8, 0.8), True)
    # The occluder: a unit-half cube scaled, turned a quarter about Y and lifted, in that order
    # of application: a 1 × 0.5 × 0.5 box centred at (0, 0.75, 0).
    occ = UsdGeom.Xform.Define(stage, "/World/Occluder")
    occ.AddTranslateOp().Set(Gf.Vec3d(0, 0.75, 0))
    occ.AddRotateYOp().Set(90.0)
    occ.AddScaleOp().Set(Gf.Vec3f(0.25, 0.25, 0.5))
    # Its points are lightfold's box of that size and place taken back through the transform,
    # so that each face's corners (and so its two triangles) come out in the box's order.
    inverse = occ.GetLocalTransformation().GetInverse()
    points, normals = cuboid((0.5, 0.25, 0.25))
    points = [inverse.Transform(p + Gf.Vec3f(0, 0.75, 0)) for p in points]
    normals = [inverse.TransformDir(n).GetNormalized() for n in normals]
    mesh(stage, "/World/Occluder/Box", points, [4] * 6, list(range(24)), normals,
         (0.7, 0.3, 0.2), False)

    cam = UsdGeom.Camera.Define(stage, "/World/Cam")
    cam.AddTranslateOp().Set(Gf.Vec3d(0, 3, 10))
    cam.AddRotateXOp().Set(-15.0)
    cam.CreateFocalLengthAttr(35.0)
    cam.CreateHorizontalApertureAttr(36.0)
    cam.CreateVerticalApertureAttr(24.0)

    lights = UsdGeom.Xform.Define(stage, "/World/Lights")
    lights.AddTranslateOp().Set(Gf.Vec3d(0, 1, 0))

    rect = UsdLux.RectLight.Define(stage, "/World/Lights/Panel")
    rect.AddTranslateOp().Set(Gf.Vec3d(-2, 2, 0))
    rect.AddRotateXOp().Set(-90.0)
    rect.CreateWidthAttr(2.0)
    rect.CreateHeightAttr(1.0)
    rect.CreateIntensityAttr(4.0)
    rect.CreateExposureAttr(1.0)
    rect.CreateColorAttr(Gf.Vec3f(1.0, 0.9, 0.8))

    disk = UsdLux.DiskLight.Define(stage, "/World/Lights/Disk")
    disk.AddTranslateOp().Set(Gf.Vec3d(2, 2, 0))
    disk.AddRotateXOp().Set(-90.0)
    disk.AddScaleOp().Set(Gf.Vec3f(2, 2, 2))
    disk.CreateRadiusAttr(0.5)
    disk.CreateIntensityAttr(10.0)
    disk.CreateExposureAttr(-1.0)
    disk.CreateNormalizeAttr(True)

    bulb = UsdLux.SphereLight.Define(stage, "/World/Lights/Bulb")
    bulb.AddTranslateOp().Set(Gf.Vec3d(0, 3, 2))
    bulb.CreateRadiusAttr(0.25)
    bulb.CreateIntensityAttr(20.0)
    bulb.CreateNormalizeAttr(True)

    point = UsdLux.SphereLight.Define(stage, "/World/Lights/Point")
    point.AddTranslateOp().Set(Gf.Vec3d(0, 4, -3))
    point.CreateRadiusAttr(0.1)
    point.CreateTreatAsPointAttr(True)
    point.CreateIntensityAttr(100.0)
    point.CreateExposureAttr(2.0)

    spot = UsdLux.SphereLight.Define(stage, "/World/Lights/Spot")
    spot.AddTranslateOp().Set(Gf.Vec3d(3, 3, -3))
    spot.AddRotateXOp().Set(-90.0)
    spot.CreateRadiusAttr(0.1)
    spot.CreateTreatAsPointAttr(True)
    spot.CreateIntensityAttr(50.0)
    shaping = UsdLux.ShapingAPI.Apply(spot.GetPrim())
    shaping.CreateShapingConeAngleAttr(30.0)
    shaping.CreateShapingConeSoftnessAttr(0.5)

    # A tube along the frame's X axis: scaled 2 along it and 0.5 across, turned a quarter about Y.
    tube = UsdLux.CylinderLight.Define(stage, "/World/Lights/Tube")
    tube.AddTranslateOp().Set(Gf.Vec3d(0, 1.5, -2))
    tube.AddRotateYOp().Set(90.0)
    tube.AddScaleOp().Set(Gf.Vec3f(2, 0.5, 0.5))
    tube.CreateLengthAttr(1.5)
    tube.CreateRadiusAttr(0.1)
    tube.CreateIntensityAttr(8.0)
    tube.CreateNormalizeAttr(True)

    sun = UsdLux.DistantLight.Define(stage, "/World/Sun")
    sun.AddRotateXOp().Set(-60.0)
    sun.CreateIntensityAttr(3.0)
    sun.CreateExposureAttr(1.0)
    sun.CreateNormalizeAttr(True)
    sun.CreateAngleAttr(2.0)
    stage.GetRootLayer().Save()
    return stage


def materials_stage(path):
    stage = Usd.Stage.CreateNew(path)
    UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.z)
    UsdGeom.SetStageMetersPerUnit(stage, 0.01)
    root = UsdGeom.Xform.Define(stage, "/Root")
    stage.SetDefaultPrim(root.GetPrim())
    mat = UsdShade.Material.Define(stage, "/Root/Looks/Gold")
    shader = UsdShade.Shader.Define(stage, "/Root/Looks/Gold/Surface")
    shader.CreateIdAttr("UsdPreviewSurface")
    shader.CreateInput("diffuseColor", Sdf.ValueTypeNames.Color3f).Set(Gf.Vec3f(1.0, 0.8, 0.3))
    shader.CreateInput("metallic", Sdf.ValueTypeNames.Float).Set(1.0)
    shader.CreateInput("roughness", Sdf.ValueTypeNames.Float).Set(0.25)
    shader.CreateInput("clearcoat", Sdf.ValueTypeNames.Float).Set(0.5)
    mat.CreateSurfaceOutput().ConnectToSource(shader.ConnectableAPI(), "surface")
    glow = UsdShade.Material.Define(stage, "/Root/Looks/Glow")
    gs = UsdShade.Shader.Define(stage, "/Root/Looks/Glow/Surface")
    gs.CreateIdAttr("UsdPreviewSurface")
    gs.CreateInput("diffuseColor", Sdf.ValueTypeNames.Color3f).Set(Gf.Vec3f(0, 0, 0))
    gs.CreateInput("emissiveColor", Sdf.ValueTypeNames.Color3f).Set(Gf.Vec3f(2.0, 4.0, 1.0))
    gs.CreateInput("opacity", Sdf.ValueTypeNames.Float).Set(0.5)
    glow.CreateSurfaceOutput().ConnectToSource(gs.ConnectableAPI(), "surface")
    # A quad 100 × 100 cm at z = 0 (Z up), bound to Gold through its parent; a triangle 50 cm
    # up bound to Glow, left-handed, with per-corner texture coordinates.
    group = UsdGeom.Xform.Define(stage, "/Root/Group")
    UsdShade.MaterialBindingAPI.Apply(group.GetPrim()).Bind(mat)
    quad = UsdGeom.Mesh.Define(stage, "/Root/Group/Quad")
    quad.CreatePointsAttr([(-50, -50, 0), (50, -50, 0), (50, 50, 0), (-50, 50, 0)])
    quad.CreateFaceVertexCountsAttr([4])
    quad.CreateFaceVertexIndicesAttr([0, 1, 2, 3])
    quad.CreateSubdivisionSchemeAttr(UsdGeom.Tokens.none)
    tri = UsdGeom.Mesh.Define(stage, "/Root/Tri")
    tri.AddTranslateOp().Set(Gf.Vec3d(0, 0, 50))
    tri.CreatePointsAttr([(0, 0, 0), (10, 0, 0), (0, 10, 0)])
    tri.CreateFaceVertexCountsAttr([3])
    tri.CreateFaceVertexIndicesAttr([0, 1, 2])
    tri.CreateOrientationAttr(UsdGeom.Tokens.leftHanded)
    tri.CreateSubdivisionSchemeAttr(UsdGeom.Tokens.none)
    st = UsdGeom.PrimvarsAPI(tri).CreatePrimvar("st", Sdf.ValueTypeNames.TexCoord2fArray,
                                                 UsdGeom.Tokens.faceVarying)
    st.Set([(0, 0), (1, 0), (0, 1)])
    UsdShade.MaterialBindingAPI.Apply(tri.GetPrim()).Bind(glow)
    UsdGeom.Cube.Define(stage, "/Root/Cube")
    UsdLux.CylinderLight.Define(stage, "/Root/Tube")
    stage.GetRootLayer().Save()


def mesh_light_stage(path):
    """A 2 m × 1 m quad 3 m up, facing down, with MeshLightAPI (normalized), over a ground."""
    stage = Usd.Stage.CreateNew(path)
    UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.y)
    mesh(stage, "/Ground", plane_points(5.0), [4], [0, 1, 2, 3], [(0, 1, 0)] * 4,
         (0.8, 0.8, 0.8), True)
    panel = UsdGeom.Mesh.Define(stage, "/Panel")
    panel.CreatePointsAttr([(-1, 3, -0.5), (1, 3, -0.5), (1, 3, 0.5), (-1, 3, 0.5)])
    panel.CreateFaceVertexCountsAttr([4])
    panel.CreateFaceVertexIndicesAttr([0, 1, 2, 3])
    panel.CreateSubdivisionSchemeAttr(UsdGeom.Tokens.none)
    light = UsdLux.MeshLightAPI.Apply(panel.GetPrim())
    lux = UsdLux.LightAPI(panel.GetPrim())
    lux.CreateIntensityAttr(6.0)
    lux.CreateExposureAttr(1.0)
    lux.CreateNormalizeAttr(True)
    lux.CreateColorAttr(Gf.Vec3f(1.0, 0.5, 0.25))
    stage.GetRootLayer().Save()


def composed_stages(folder):
    """A stage built from a reference, a payload and a sublayer, all inside its folder; and the
    hostile ones: a reference outside the folder, an absolute one, and a reference cycle."""
    os.makedirs(os.path.join(folder, "parts"), exist_ok=True)
    part = Usd.Stage.CreateNew(os.path.join(folder, "parts", "box.usda"))
    xf = UsdGeom.Xform.Define(part, "/Box")
    part.SetDefaultPrim(xf.GetPrim())
    points, normals = cuboid((0.5, 0.5, 0.5))
    mesh(part, "/Box/Mesh", points, [4] * 6, list(range(24)), normals, (0.2, 0.4, 0.9), False)
    part.GetRootLayer().Save()
    light = Usd.Stage.CreateNew(os.path.join(folder, "parts", "light.usda"))
    rect = UsdLux.RectLight.Define(light, "/Key")
    light.SetDefaultPrim(rect.GetPrim())
    rect.AddTranslateOp().Set(Gf.Vec3d(0, 4, 0))
    rect.AddRotateXOp().Set(-90.0)
    rect.CreateIntensityAttr(5.0)
    light.GetRootLayer().Save()
    sub = Usd.Stage.CreateNew(os.path.join(folder, "parts", "ground.usda"))
    mesh(sub, "/Ground", plane_points(4.0), [4], [0, 1, 2, 3], [(0, 1, 0)] * 4, (0.5, 0.5, 0.5),
         True)
    sub.GetRootLayer().Save()

    main = Usd.Stage.CreateNew(os.path.join(folder, "composed.usda"))
    main.GetRootLayer().subLayerPaths.append("./parts/ground.usda")
    for k, x in enumerate((-1.5, 1.5)):
        inst = UsdGeom.Xform.Define(main, f"/Box{k}")
        inst.AddTranslateOp().Set(Gf.Vec3d(x, 0.5, 0))
        inst.GetPrim().GetReferences().AddReference("./parts/box.usda")
        inst.GetPrim().SetInstanceable(True)
    key = main.DefinePrim("/Key")
    key.GetPayloads().AddPayload("./parts/light.usda")
    main.GetRootLayer().Save()

    def referencing(name, target):
        s = Usd.Stage.CreateNew(os.path.join(folder, name))
        p = s.DefinePrim("/Thing")
        s.SetDefaultPrim(p)
        p.GetReferences().AddReference(target)
        s.GetRootLayer().Save()

    referencing("outside.usda", "../outside.usda")
    referencing("absolute.usda", "/etc/hosts.usda")
    referencing("cycle_a.usda", "./cycle_b.usda")
    referencing("cycle_b.usda", "./cycle_a.usda")
    sub_out = Usd.Stage.CreateNew(os.path.join(folder, "sublayer_outside.usda"))
    sub_out.GetRootLayer().subLayerPaths.append("../../data.usda")
    sub_out.GetRootLayer().Save()


def main():
    out = sys.argv[1] if len(sys.argv) > 1 else ROOT
    # Rewrites its own stages only: moving.usda is written by hand beside them.
    os.makedirs(out, exist_ok=True)
    stage = lights_stage(os.path.join(out, "lights.usda"))
    stage.GetRootLayer().Export(os.path.join(out, "lights.usdc"))
    UsdUtils.CreateNewUsdzPackage(os.path.join(out, "lights.usdc"), os.path.join(out, "lights.usdz"))
    materials_stage(os.path.join(out, "materials.usda"))
    mesh_light_stage(os.path.join(out, "meshlight.usda"))
    composed_stages(out)


if __name__ == "__main__":
    main()
