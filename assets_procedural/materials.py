"""Procedural PBR materials (Principled BSDF node trees), cached by name so objects rebuilt
every frame reuse them instead of piling up new datablocks."""

from __future__ import annotations

import bpy


def _key(prefix: str, color) -> str:
    return prefix + "_" + "_".join(f"{c:.2f}" for c in color[:3])


def _new(name: str):
    m = bpy.data.materials.get(name)
    if m is not None:
        return m, False
    m = bpy.data.materials.new(name)
    if m.node_tree is None:  # bpy < 5 needs node trees switched on (deprecated in 5.0)
        m.use_nodes = True
    return m, True


def _bsdf(m):
    return m.node_tree.nodes["Principled BSDF"]


def principled(name: str, color, roughness=0.5, metallic=0.0, coat=0.0, coat_roughness=0.03,
               transmission=0.0, ior=1.45, emission=None, emission_strength=0.0, subsurface=0.0,
               sheen=0.0):
    m, new = _new(name)
    if not new:
        return m
    return _setup(m, color, roughness, metallic, coat, coat_roughness, transmission, ior, emission,
                  emission_strength, subsurface, sheen)


def _setup(m, color, roughness=0.5, metallic=0.0, coat=0.0, coat_roughness=0.03, transmission=0.0, ior=1.45,
           emission=None, emission_strength=0.0, subsurface=0.0, sheen=0.0):
    b = _bsdf(m)
    b.inputs["Base Color"].default_value = (*color[:3], 1.0)
    b.inputs["Roughness"].default_value = roughness
    b.inputs["Metallic"].default_value = metallic
    b.inputs["Coat Weight"].default_value = coat
    b.inputs["Coat Roughness"].default_value = coat_roughness
    b.inputs["Transmission Weight"].default_value = transmission
    b.inputs["IOR"].default_value = ior
    b.inputs["Subsurface Weight"].default_value = subsurface
    b.inputs["Sheen Weight"].default_value = sheen
    if emission is not None:
        b.inputs["Emission Color"].default_value = (*emission[:3], 1.0)
        b.inputs["Emission Strength"].default_value = emission_strength
    m.diffuse_color = (*color[:3], 1.0)
    m["blendgen_kind"] = m.name.split("_")[0]
    return m


# ---- object materials
def paint(color, metallic=0.3, wear=0.0):
    """Car paint: a base coat with metallic flakes (fine Voronoi bump on the base layer only)
    under a glossy clear coat; `wear` adds road grime toward the sills and wheel arches."""
    m, new = _new(_key(f"paint_m{metallic:.1f}w{wear:.1f}", color))
    if not new:
        return m
    _setup(m, color, roughness=0.38, metallic=metallic, coat=1.0, coat_roughness=0.03)
    nt, b = m.node_tree, _bsdf(m)
    coord = nt.nodes.new("ShaderNodeTexCoord").outputs["Object"]
    if metallic > 0.2:
        flakes = nt.nodes.new("ShaderNodeTexVoronoi")
        flakes.inputs["Scale"].default_value = 900.0
        nt.links.new(coord, flakes.inputs["Vector"])
        bump = nt.nodes.new("ShaderNodeBump")
        bump.inputs["Strength"].default_value = 0.08
        nt.links.new(flakes.outputs["Distance"], bump.inputs["Height"])
        nt.links.new(bump.outputs["Normal"], b.inputs["Normal"])  # the coat stays smooth
    if wear > 0:
        grime = _grime_mask(nt, coord, wear)
        dirt = nt.nodes.new("ShaderNodeMix")
        dirt.data_type = "RGBA"
        nt.links.new(grime, dirt.inputs["Factor"])
        dirt.inputs["A"].default_value = (*color[:3], 1.0)
        dirt.inputs["B"].default_value = (0.10, 0.085, 0.065, 1.0)
        nt.links.new(dirt.outputs["Result"], b.inputs["Base Color"])
        rough = nt.nodes.new("ShaderNodeMapRange")
        nt.links.new(grime, rough.inputs["Value"])
        rough.inputs["To Min"].default_value, rough.inputs["To Max"].default_value = 0.03, 0.6
        nt.links.new(rough.outputs["Result"], b.inputs["Coat Roughness"])
    return m


def _grime_mask(nt, coord, wear):
    """0..1 grime: strongest at the bottom (object z in metres), broken up by noise."""
    sep = nt.nodes.new("ShaderNodeSeparateXYZ")
    nt.links.new(coord, sep.inputs[0])
    low = nt.nodes.new("ShaderNodeMapRange")
    nt.links.new(sep.outputs["Z"], low.inputs["Value"])
    low.inputs["From Min"].default_value, low.inputs["From Max"].default_value = 0.1, 0.9
    low.inputs["To Min"].default_value, low.inputs["To Max"].default_value = wear, 0.0
    n = _noise(nt, 3.0, 6.0, coord)
    mul = nt.nodes.new("ShaderNodeMath")
    mul.operation = "MULTIPLY"
    nt.links.new(low.outputs["Result"], mul.inputs[0])
    nt.links.new(n.outputs["Factor"], mul.inputs[1])
    return mul.outputs[0]


CABIN_SEATS = (0.68, 0.80)  # seat backs to headrests, share of a car's height: the cabin hides the view below


def glass(tint=(0.006, 0.008, 0.009), see_through=0.0, seats=CABIN_SEATS):
    """Tinted car glass: a dark cabin behind a smooth dielectric that mirrors the environment
    (Fresnel: dark face-on, bright at grazing angles), as windows look from outside.
    `see_through`: the share of the window that is a holdout, through which the composite shows
    the real frame: what a camera sees through a car's windows is the street beyond it. The
    cabin is not modelled: below the seat backs' height (`seats`, shares of the vehicle's height)
    the glass stays dark, above it the share rises to `see_through`."""
    m, new = _new(_key(f"glass_s{see_through:.2f}_{seats[0]:.2f}-{seats[1]:.2f}", tint))
    if not new:
        return m
    _setup(m, tint, roughness=0.015, ior=1.52)
    if see_through > 0:
        nt = m.node_tree
        mix, hold = nt.nodes.new("ShaderNodeMixShader"), nt.nodes.new("ShaderNodeHoldout")
        gen, xyz = nt.nodes.new("ShaderNodeTexCoord"), nt.nodes.new("ShaderNodeSeparateXYZ")
        ramp = nt.nodes.new("ShaderNodeMapRange")  # clamps to [To Min, To Max]
        ramp.inputs["From Min"].default_value, ramp.inputs["From Max"].default_value = seats
        ramp.inputs["To Min"].default_value, ramp.inputs["To Max"].default_value = 0.0, see_through
        nt.links.new(gen.outputs["Generated"], xyz.inputs[0])  # 0..1 over the object's bounds
        nt.links.new(xyz.outputs["Z"], ramp.inputs["Value"])
        nt.links.new(ramp.outputs["Result"], mix.inputs["Fac"])
        nt.links.new(_bsdf(m).outputs[0], mix.inputs[1])
        nt.links.new(hold.outputs[0], mix.inputs[2])
        nt.links.new(mix.outputs[0], nt.nodes["Material Output"].inputs["Surface"])
    return m


def rubber():
    return principled("rubber", (0.018, 0.018, 0.018), roughness=0.85)


def chrome():
    return principled("chrome", (0.9, 0.9, 0.92), roughness=0.08, metallic=1.0)


def alloy():
    return principled("alloy", (0.6, 0.6, 0.62), roughness=0.3, metallic=1.0)


def plastic(color=(0.03, 0.03, 0.03)):
    return principled(_key("plastic", color), color, roughness=0.55)


def fabric(color):
    return principled(_key("fabric", color), color, roughness=0.9, sheen=0.6)


def skin(color):
    return principled(_key("skin", color), color, roughness=0.55, subsurface=0.25)


def hair(color):
    return principled(_key("hair", color), color, roughness=0.45, sheen=0.4)


def lamp(color, strength):
    """A light: emission in `color` (signal lamps). An unlit lens is dark glass with a tint:
    a diffuse colour of 0.3 read as a lit lamp in daylight on real photos."""
    base = 0.3 if strength >= 1.0 else 0.04
    return principled(_key(f"lamp{strength:g}", color), [c * base for c in color], roughness=0.1,
                      emission=color, emission_strength=strength, coat=1.0)


# vehicle lamps: (lens colour, emission colour, strength off, strength on); the render driver
# switches them per frame from the plan's lighting["lights_on"] (set_vehicle_lamps)
VEHICLE_LAMPS = {"head": ((0.8, 0.8, 0.8), (1.0, 0.93, 0.8), 0.0, 40.0),
                 "tail": ((0.45, 0.01, 0.01), (1.0, 0.008, 0.011), 0.2, 12.0),
                 "sign": ((0.3, 0.2, 0.05), (1.0, 0.55, 0.05), 0.5, 6.0)}


def vehicle_lamp(kind: str, on: bool | None = None):
    lens, emit, off_s, on_s = VEHICLE_LAMPS[kind]
    m, new = _new(f"vlamp_{kind}")
    if new:
        _setup(m, lens, roughness=0.05, emission=emit, emission_strength=off_s, coat=1.0)
        m["blendgen_lamp"] = kind
    if on is not None:
        _bsdf(m).inputs["Emission Strength"].default_value = on_s if on else off_s
    return m


def set_vehicle_lamps(on: bool) -> int:
    """Head/tail lamps on (night, dusk) or off (day) for every vehicle lamp material; returns
    how many materials were set."""
    mats = [m for m in bpy.data.materials if "blendgen_lamp" in m]
    for m in mats:
        vehicle_lamp(m["blendgen_lamp"], on)
    return len(mats)


def metal(color=(0.55, 0.56, 0.58), roughness=0.4):
    return principled(_key(f"metal{roughness:g}", color), color, roughness=roughness, metallic=1.0)


# ---- twin materials with procedural texture
def _noise(nt, scale, detail=6.0, coord=None):
    n = nt.nodes.new("ShaderNodeTexNoise")
    n.inputs["Scale"].default_value = scale
    n.inputs["Detail"].default_value = detail
    if coord is not None:
        nt.links.new(coord, n.inputs["Vector"])
    return n


def _ramp(nt, fac, c0, c1, p0=0.35, p1=0.65):
    r = nt.nodes.new("ShaderNodeValToRGB")
    r.color_ramp.elements[0].position, r.color_ramp.elements[1].position = p0, p1
    r.color_ramp.elements[0].color = (*c0, 1.0)
    r.color_ramp.elements[1].color = (*c1, 1.0)
    nt.links.new(fac, r.inputs["Fac"])
    return r


def asphalt(color=(0.05, 0.05, 0.052), roughness=0.85, wear=0.5):
    """Asphalt with worn, lighter patches and fine aggregate bump."""
    m, new = _new(_key(f"asphalt{wear:.2f}", color))
    if not new:
        return m
    nt, b = m.node_tree, _bsdf(m)
    coord = nt.nodes.new("ShaderNodeTexCoord").outputs["Object"]
    patches = _noise(nt, 0.15, 4.0, coord)
    light = [min(1.0, c * (1.0 + 1.6 * wear)) for c in color]
    ramp = _ramp(nt, patches.outputs["Factor"], color, light, 0.4, 0.7)
    nt.links.new(ramp.outputs["Color"], b.inputs["Base Color"])
    grain = _noise(nt, 180.0, 2.0, coord)
    bump = nt.nodes.new("ShaderNodeBump")
    bump.inputs["Strength"].default_value = 0.25
    nt.links.new(grain.outputs["Factor"], bump.inputs["Height"])
    nt.links.new(bump.outputs["Normal"], b.inputs["Normal"])
    b.inputs["Roughness"].default_value = roughness
    m.diffuse_color = (*color, 1.0)
    return m


def road_paint(color=(0.85, 0.85, 0.82)):
    m, new = _new(_key("marking", color))
    if not new:
        return m
    nt, b = m.node_tree, _bsdf(m)
    coord = nt.nodes.new("ShaderNodeTexCoord").outputs["Object"]
    worn = _noise(nt, 2.5, 5.0, coord)
    ramp = _ramp(nt, worn.outputs["Factor"], [c * 0.55 for c in color], color, 0.3, 0.55)
    nt.links.new(ramp.outputs["Color"], b.inputs["Base Color"])
    b.inputs["Roughness"].default_value = 0.6
    return m


def concrete(color=(0.55, 0.54, 0.52), tiles=True, name="sidewalk"):
    """Concrete; with `tiles`, paving slabs from a brick texture (grooves dark and bumped)."""
    m, new = _new(_key(name, color))
    if not new:
        return m
    nt, b = m.node_tree, _bsdf(m)
    coord = nt.nodes.new("ShaderNodeTexCoord").outputs["Object"]
    dirt = _noise(nt, 0.8, 5.0, coord)
    ramp = _ramp(nt, dirt.outputs["Factor"], [c * 0.75 for c in color], color, 0.3, 0.7)
    if tiles:
        br = nt.nodes.new("ShaderNodeTexBrick")
        br.inputs["Scale"].default_value = 1.0
        br.inputs["Brick Width"].default_value = 0.6
        br.inputs["Row Height"].default_value = 0.6
        br.inputs["Mortar Size"].default_value = 0.012
        br.offset = 0.0
        nt.links.new(coord, br.inputs["Vector"])
        nt.links.new(ramp.outputs["Color"], br.inputs["Color1"])
        nt.links.new(ramp.outputs["Color"], br.inputs["Color2"])
        br.inputs["Mortar"].default_value = (*[c * 0.4 for c in color], 1.0)
        nt.links.new(br.outputs["Color"], b.inputs["Base Color"])
        bump = nt.nodes.new("ShaderNodeBump")
        bump.inputs["Strength"].default_value = 0.4
        nt.links.new(br.outputs["Fac"], bump.inputs["Height"])
        nt.links.new(bump.outputs["Normal"], b.inputs["Normal"])
    else:
        nt.links.new(ramp.outputs["Color"], b.inputs["Base Color"])
    b.inputs["Roughness"].default_value = 0.9
    return m


def grass(color=(0.10, 0.16, 0.05)):
    m, new = _new(_key("ground", color))
    if not new:
        return m
    nt, b = m.node_tree, _bsdf(m)
    coord = nt.nodes.new("ShaderNodeTexCoord").outputs["Object"]
    n = _noise(nt, 0.3, 6.0, coord)
    ramp = _ramp(nt, n.outputs["Factor"], [c * 0.6 for c in color], [min(1, c * 1.5) for c in color])
    nt.links.new(ramp.outputs["Color"], b.inputs["Base Color"])
    b.inputs["Roughness"].default_value = 0.95
    return m


def facade(color, floor_h=3.2, bay_w=2.6):
    """A facade with a grid of glossy windows (from object coordinates in metres)."""
    m, new = _new(_key(f"facade{floor_h:.1f}", color))
    if not new:
        return m
    nt = m.node_tree
    b = _bsdf(m)
    out = nt.nodes["Material Output"]
    coord = nt.nodes.new("ShaderNodeTexCoord")
    sep = nt.nodes.new("ShaderNodeSeparateXYZ")
    nt.links.new(coord.outputs["Object"], sep.inputs[0])

    def math_node(op, a, bval=None):
        n = nt.nodes.new("ShaderNodeMath")
        n.operation = op
        if isinstance(a, float):
            n.inputs[0].default_value = a
        else:
            nt.links.new(a, n.inputs[0])
        if bval is not None:
            if isinstance(bval, float):
                n.inputs[1].default_value = bval
            else:
                nt.links.new(bval, n.inputs[1])
        return n.outputs[0]

    # bands: windows between 30% and 80% of each floor, 20-80% of each bay; not on roofs
    zf = math_node("FRACT", math_node("DIVIDE", sep.outputs["Z"], floor_h))
    zin = math_node("MULTIPLY", math_node("GREATER_THAN", zf, 0.3), math_node("LESS_THAN", zf, 0.8))
    u = math_node("ADD", sep.outputs["X"], sep.outputs["Y"])
    uf = math_node("FRACT", math_node("DIVIDE", u, bay_w))
    uin = math_node("MULTIPLY", math_node("GREATER_THAN", uf, 0.22), math_node("LESS_THAN", uf, 0.78))
    low = math_node("GREATER_THAN", sep.outputs["Z"], 0.6)
    nz = nt.nodes.new("ShaderNodeSeparateXYZ")
    nt.links.new(coord.outputs["Normal"], nz.inputs[0])
    wall = math_node("LESS_THAN", math_node("ABSOLUTE", nz.outputs["Z"]), 0.5)
    mask = math_node("MULTIPLY", math_node("MULTIPLY", zin, uin), math_node("MULTIPLY", low, wall))
    dirt = _noise(nt, 1.5, 4.0, coord.outputs["Object"])
    ramp = _ramp(nt, dirt.outputs["Factor"], [c * 0.8 for c in color], color, 0.3, 0.7)
    nt.links.new(ramp.outputs["Color"], b.inputs["Base Color"])
    b.inputs["Roughness"].default_value = 0.85
    win = nt.nodes.new("ShaderNodeBsdfPrincipled")
    win.inputs["Base Color"].default_value = (0.04, 0.05, 0.06, 1.0)
    win.inputs["Roughness"].default_value = 0.04
    win.inputs["Metallic"].default_value = 0.6
    mix = nt.nodes.new("ShaderNodeMixShader")
    nt.links.new(mask, mix.inputs["Fac"])
    nt.links.new(b.outputs["BSDF"], mix.inputs[1])
    nt.links.new(win.outputs["BSDF"], mix.inputs[2])
    nt.links.new(mix.outputs["Shader"], out.inputs["Surface"])
    m.diffuse_color = (*color, 1.0)
    return m


def bark():
    return principled("bark", (0.09, 0.06, 0.04), roughness=0.9)


def foliage(color=(0.05, 0.14, 0.03)):
    m, new = _new(_key("foliage", color))
    if not new:
        return m
    nt, b = m.node_tree, _bsdf(m)
    coord = nt.nodes.new("ShaderNodeTexCoord").outputs["Object"]
    n = _noise(nt, 4.0, 8.0, coord)
    ramp = _ramp(nt, n.outputs["Factor"], [c * 0.5 for c in color], [min(1, c * 1.8) for c in color])
    nt.links.new(ramp.outputs["Color"], b.inputs["Base Color"])
    bump = nt.nodes.new("ShaderNodeBump")
    bump.inputs["Strength"].default_value = 0.8
    nt.links.new(n.outputs["Factor"], bump.inputs["Height"])
    nt.links.new(bump.outputs["Normal"], b.inputs["Normal"])
    b.inputs["Roughness"].default_value = 0.8
    b.inputs["Sheen Weight"].default_value = 0.3
    return m
