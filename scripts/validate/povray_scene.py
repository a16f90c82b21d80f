"""Writes a POV-Ray 3.7 scene that renders a freeform scene's receiver irradiance with
photon mapping, from the scene (freeform's effective-scene JSON) and the exported mesh.

Choices, and why (docs: README "Independent validation"):
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
- The receiver is a diffuse plane (ambient 0, diffuse 1, no specular/phong) that collects
  photons. It sits in a `light_group` with `global_lights off`, so the light does not
  illuminate it directly (freeform records only light that has left the surface); photons
  still land on it. The light is placed between the surface and the receiver (DESIGN.md:
  the receiver is transparent to the incoming light); a parallel light's photons start at
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


def write_scene(path, scene, mesh_path, width, height, photon_count, gather=(100, 400)):
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
        pos = mid - d * (np.dot(s_w, mid - s_origin) + top + 0.05 * dist + 0.01)
        light_src = "light_source { %s color rgb 1 parallel point_at %s\n  photons { reflection on refraction on } }" % (
            vec(pos * MM), vec(mid * MM))
    elif light["type"] == "point":
        if light.get("profile"):
            raise ValueError("a point light's intensity profile has no POV-Ray equivalent here")
        light_src = "light_source { %s color rgb 1\n  photons { reflection on refraction on } }" % vec(
            np.asarray(light["position"]) * MM)
    else:
        raise ValueError("light type %r is not validated" % light["type"])

    if lens:
        body = mesh2(vertices, triangles) + "\n  inside_vector %s\n" % vec(s_w) + (
            "  texture { pigment { rgbf <1, 1, 1, 1> } finish { ambient 0 emission 0 diffuse 0 specular 0 phong 0 reflection 0 } }\n"
            "  interior { ior %.6g }\n"
            "  photons { target refraction on reflection off collect off }\n}" % material["refractive"])
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
