"""Writes a POV-Ray 3.7 scene that renders a freeform scene's receiver irradiance with
photon mapping, from the scene (freeform's effective-scene JSON) and the exported mesh.

Choices, and why (docs/measures.md, "An independent check: POV-Ray"):
- Millimetres: the scene is scaled by 1000. POV-Ray's intersection tolerances are absolute
  (about 1e-4 to 1e-3 units); in metres a 0.1 mm facet would be near them.
- The mirror is a `mesh2` of the exported sheet (flat triangles: no normal_vectors, so
  POV-Ray traces the facets the machine would cut, as `freeform render --mesh` does), with
  `reflection 1` (no Fresnel, no metallic tint). The lens is the exported closed solid
  (`inside_vector`), clear (`filter 1`), `ior` from the scene, no `fade_distance`, and no
  reflection, so no Fresnel loss: freeform neglects it too.
- Light: `parallel` for a collimated light, a plain point light for a point light (POV-Ray
  lights have no distance falloff by default, and photons are shot evenly over solid angle,
  so the photon density on the mirror is the physical cos/r^2 of an isotropic source).
- A collimated light with an angular radius (the sun's disc) becomes `sun_lights` parallel
  lights of power 1/N each, their directions spread evenly over the disc's solid angle
  (equal-area rings, a golden-angle spiral): a discretisation of our own, independent of
  freeform's 8-direction ring-and-sector sampler. POV-Ray's `area_light` cannot stand in:
  it moves a light's origin, not its direction, and photons leave from its centre.
- Fresnel (scene `trace.fresnel`, lenses only): the lens finish gets `reflection { 0, 1
  fresnel on } conserve_energy`, so what a face reflects is taken from what it transmits
  (POV-Ray's own Fresnel formula), and the lens's photons do not follow reflection, as
  freeform drops the reflected part (docs/scene.md).
- The receiver is a diffuse plane (ambient 0, diffuse 1, no specular/phong) that collects
  photons. It sits in a `light_group` with `global_lights off`, so the light does not
  illuminate it directly (freeform records only light that has left the surface); photons
  still land on it. The light is placed between the surface and the receiver (docs/architecture.md
  §1: the receiver is transparent to the incoming light); a parallel light's photons start at
  its position, so the receiver never shadows them.
- An orthographic camera on the receiver's front looks along -normal; its `right` and `up`
  are the receiver's u and v axes times its size, so it frames exactly the receiver
  rectangle and the picture has freeform's orientation (columns along u, row 0 at +v).
- Photons only target the surface: they are shot at the mirror or lens alone. The surface
  carries neither `no_shadow` nor `no_image`: either flag makes POV-Ray 3.7 store no
  photons from it (measured). It needs neither: the orthographic camera's rays start on its
  plane, between the surface and the receiver, and the receiver casts no shadow rays
  (its light group has no lit light).
"""
import numpy as np

MM = 1000.0  # scene units per metre


def unit(v):
    v = np.asarray(v, dtype=float)
    return v / np.linalg.norm(v)


def frame(center, normal, up):
    """freeform's plane frame (docs/scene.md): w = normal, v = up made orthogonal, u = v x w."""
    w = unit(normal)
    up = np.asarray(up, dtype=float)
    v = unit(up - np.dot(up, w) * w)
    u = np.cross(v, w)
    return np.asarray(center, dtype=float), u, v, w


def read_obj(path):
    """Vertices (n, 3) and triangles (m, 3, zero-based) of an OBJ file (v and f lines)."""
    verts, faces = [], []
    with open(path) as f:
        for line in f:
            if line.startswith("v "):
                verts.append(line.split()[1:4])
            elif line.startswith("f "):
                faces.append([int(t.split("/")[0]) for t in line.split()[1:4]])
    return np.asarray(verts, dtype=float), np.asarray(faces, dtype=np.int64) - 1


def vec(p):
    return "<%.9g, %.9g, %.9g>" % tuple(p)


def mesh2(vertices, triangles):
    out = ["mesh2 {", "  vertex_vectors { %d," % len(vertices)]
    out.append(",\n".join("<%.9g,%.9g,%.9g>" % tuple(p) for p in vertices * MM))
    out.append("  }")
    out.append("  face_indices { %d," % len(triangles))
    out.append(",\n".join("<%d,%d,%d>" % tuple(t) for t in triangles))
    out.append("  }")
    return "\n".join(out)


def sun_directions(d, angular_radius_deg, n):
    """(direction, power) pairs: d alone for parallel light; otherwise n directions spread
    evenly over the cone of the given angular radius around d (equal solid angle each: ring
    k of n sits where 1 - cos a = (1 - cos theta)(k + 1/2)/n, turned by the golden angle)."""
    if angular_radius_deg <= 0:
        return [(d, 1.0)]
    theta = np.radians(angular_radius_deg)
    e1 = np.cross(d, [0.0, 1.0, 0.0] if abs(d[1]) < 0.9 else [1.0, 0.0, 0.0])
    e1 = unit(e1)
    e2 = np.cross(d, e1)
    golden = np.pi * (3.0 - np.sqrt(5.0))
    out = []
    for k in range(n):
        cos_a = 1.0 - (1.0 - np.cos(theta)) * (k + 0.5) / n
        sin_a = np.sqrt(max(0.0, 1.0 - cos_a * cos_a))
        phi = k * golden
        out.append((cos_a * d + sin_a * (np.cos(phi) * e1 + np.sin(phi) * e2), 1.0 / n))
    return out


def write_scene(path, scene, mesh_path, width, height, photon_count, gather=(100, 400), sun_lights=64):
    """Writes the .pov file; width x height are the picture's pixels (any multiple of the
    receiver's resolution: the caller bins them down)."""
    surf, rec, light = scene["surface"], scene["receiver"], scene["light"]
    s_origin, _, _, s_w = frame(surf["center"], surf["normal"], surf["up"])
    r_origin, r_u, r_v, r_w = frame(rec["center"], rec["normal"], rec["up"])
    material = surf["material"]
    lens = isinstance(material, dict)
    vertices, triangles = read_obj(mesh_path)

    # Where light goes once it has left the surface: towards the receiver.
    dist = float(np.linalg.norm(r_origin - s_origin))
    top = float(surf["height_bounds"][1])
    if light["type"] == "collimated":
        d = unit(light["direction"])
        # Just in front of the surface (clear of its highest point), between it and the receiver.
        # POV-Ray aims a parallel light's photons from its position at point_at: both must lie
        # on the axis through the middle of the target (measured: an off-axis parallel light
        # stores no photons).
        mid = 0.5 * (vertices.min(axis=0) + vertices.max(axis=0))
        reach = np.dot(s_w, mid - s_origin) + top + 0.05 * dist + 0.01
        light_src = "\n".join(
            "light_source { %s color rgb %.9g parallel point_at %s\n  photons { reflection on refraction on } }" % (
                vec((mid - dk * reach) * MM), power, vec(mid * MM))
            for dk, power in sun_directions(d, float(light.get("angular_radius", 0.0)), sun_lights))
    elif light["type"] == "point":
        if light.get("profile"):
            raise ValueError("a point light's intensity profile has no POV-Ray equivalent here")
        light_src = "light_source { %s color rgb 1\n  photons { reflection on refraction on } }" % vec(
            np.asarray(light["position"]) * MM)
    else:
        raise ValueError("light type %r is not validated" % light["type"])

    if lens:
        fresnel = bool(scene.get("trace", {}).get("fresnel", False))
        reflect = "reflection { 0, 1 fresnel on } conserve_energy" if fresnel else "reflection 0"
        body = mesh2(vertices, triangles) + "\n  inside_vector %s\n" % vec(s_w) + (
            "  texture { pigment { rgbf <1, 1, 1, 1> } finish { ambient 0 emission 0 diffuse 0 specular 0 phong 0 %s } }\n"
            "  interior { ior %.6g }\n"
            "  photons { target refraction on reflection off collect off }\n}" % (reflect, material["refractive"]))
    else:
        body = mesh2(vertices, triangles) + (
            "\n  texture { pigment { rgb 1 } finish { ambient 0 emission 0 diffuse 0 specular 0 phong 0 reflection { 1 } } }\n"
            "  photons { target reflection on refraction off collect off }\n}")

    size = np.asarray(rec["size"], dtype=float)
    cam_dist = 0.02 * dist  # close to the receiver, on its front: nothing else in between
    cam = r_origin + r_w * cam_dist
    gmin, gmax = gather
    text = f"""// Written by scripts/validate/povray_scene.py: freeform scene {scene.get('name', '')!r}, units mm.
#version 3.7;
global_settings {{
  assumed_gamma 1.0
  max_trace_level 16
  adc_bailout 0
  ambient_light 0
  photons {{ count {photon_count} autostop 0 jitter 0.4 gather {gmin}, {gmax} max_trace_level 16 adc_bailout 0 }}
}}
{light_src}
// The receiver: lit only by photons (global_lights off keeps the light's direct term away).
light_group {{
  plane {{ {vec(r_w)}, {np.dot(r_w, r_origin) * MM:.9g}
    texture {{ pigment {{ rgb 1 }} finish {{ ambient 0 emission 0 diffuse 1 brilliance 1 specular 0 phong 0 reflection 0 }} }}
    photons {{ collect on }}
  }}
  light_source {{ {vec((r_origin + r_w * dist) * MM)} color rgb 0 }}
  global_lights off
}}
camera {{ orthographic
  location {vec(cam * MM)}
  direction {vec(-r_w)}
  right {vec(r_u * size[0] * MM)}
  up {vec(r_v * size[1] * MM)}
}}
{body}
"""
    with open(path, "w") as f:
        f.write(text)
    return {"triangles": int(len(triangles)), "vertices": int(len(vertices))}
