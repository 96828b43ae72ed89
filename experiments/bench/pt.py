"""Path-tracing throughput on the Cornell box: jgi against Mitsuba 3 measured in the same run.

    python -m experiments.bench.pt [--spp 64] [--resolution 256] [--devices N] [--no-mitsuba]
                                   [--objects blocks|spheres|veach_ggx|envmap|fog|milk|cloud]
                                   [--json out.json]

Both render the same scene (jgi's ``cornell_box`` replicates Mitsuba's ``cornell_box()``) at
max depth 8 with Russian roulette from depth 5, NEE + MIS. Prints compile time, million paths
per second for each (wall clock, and per CPU-second of the process, which is less sensitive to
other jobs on a shared machine), their ratio, and the image means (to check both compute the
same thing). Mitsuba uses its ``llvm_ad_rgb`` variant (needs ``DRJIT_LIBLLVM_PATH`` pointing
at LLVM 19's ``libLLVM.so.19.1``; set automatically when Debian's ``libllvm19`` is installed).

``--objects spheres`` replaces the two blocks, in both renderers, by two diffuse spheres of
radius 0.35 (five walls, two spheres and an area light: the scene of the prototype that issue 2's
5x target was derived from). ``--objects envmap`` renders a diffuse and a rough-conductor
ball on a floor under a latitude-longitude sky map with a sun (an EXR written here; both load
the same Mitsuba XML: environment-map importance sampling and MIS).
``--objects veach_ggx`` renders Veach's MIS plates with GGX rough-conductor plates instead
(``jgi.scenes.veach_plates_ggx``, translated for Mitsuba by
``experiments/mitsuba_scene.py``): the glossy case, where most of the time goes to microfacet
evaluation and sampling.
``--objects fog`` renders the Cornell box filled with a homogeneous fog (``cornell_box_fog``:
sigma_t 0.6, albedo 0.8, isotropic; Mitsuba: the same medium on the sensor, so that it fills
the room, rendered by its ``volpath`` integrator): free-flight sampling, NEE from medium
vertices with the transmittance of the shadow ray, and phase sampling.
``--objects milk`` renders a backlit rough glass ball holding milk-like fog (jgi's ``milk_ball``
without haze; both load the same Mitsuba XML, the fog the sphere's interior medium): a medium
bounded by a shape, each lane carrying its medium's id. ``--objects cloud`` puts a 32^3 density
grid (a blob, written as a .vol file) in a turned null cube under the same light instead (one
Mitsuba XML both load): jgi's grid medium in a frame of its own, tracked against its majorant
grid, against Mitsuba's heterogeneous medium.

By default jgi traces the image with two concurrent loops on one CPU device (see
``jgi.core.calls``), and XLA splits each of their large kernels over the cores.
``--devices N`` splits the work over N virtual CPU devices instead
(``--xla_force_host_platform_device_count``, set before JAX starts), each compiling its own copy.
"""

from __future__ import annotations

import argparse
import glob
import json
import os
import sys
import time

import numpy as np

SPHERES = [((-0.45, -0.65, -0.3), 0.35), ((0.45, -0.65, 0.3), 0.35)]   # (centre, radius)
ENVMAP_XML = """<scene version="3.0.0">
  <integrator type="path"><integer name="max_depth" value="8"/><integer name="rr_depth" value="5"/>
  </integrator>
  <sensor type="perspective"><float name="fov" value="40"/>
    <transform name="to_world"><lookat origin="0, 1.5, 4" target="0, -0.2, 0" up="0, 1, 0"/>
    </transform>
    <film type="hdrfilm"><integer name="width" value="{res}"/><integer name="height" value="{res}"/>
      <rfilter type="box"/></film>
  </sensor>
  <shape type="sphere"><point name="center" x="-0.6" y="0" z="0"/>
    <float name="radius" value="0.6"/>
    <bsdf type="diffuse"><rgb name="reflectance" value="0.7, 0.3, 0.2"/></bsdf></shape>
  <shape type="sphere"><point name="center" x="0.7" y="0" z="0.2"/>
    <float name="radius" value="0.6"/>
    <bsdf type="roughconductor"><string name="material" value="Au"/>
      <float name="alpha" value="0.2"/></bsdf></shape>
  <shape type="rectangle"><transform name="to_world"><scale value="4"/><rotate x="1" angle="-90"/>
    <translate y="-0.6"/></transform>
    <bsdf type="diffuse"><rgb name="reflectance" value="0.6"/></bsdf></shape>
  <emitter type="envmap"><string name="filename" value="sky.exr"/>
    <transform name="to_world"><rotate y="1" angle="60"/></transform></emitter>
</scene>
"""


def envmap_scene_file(resolution: int) -> str:
    """The envmap bench scene as a Mitsuba XML file (and its sky EXR) in a temporary folder."""
    import tempfile

    from jgi.core.imageio import write_exr

    folder = tempfile.mkdtemp(prefix="bench_envmap_")
    H, W = 64, 128
    up = 0.5 * (1 + np.cos(np.pi * np.arange(H) / (H - 1)))[:, None, None]
    sky = np.broadcast_to(0.05 + np.array([0.4, 0.6, 1.0]) * up, (H, W, 3)).copy()
    sky[14:17, 40:44] = (400.0, 350.0, 300.0)    # the sun
    write_exr(os.path.join(folder, "sky.exr"), sky)
    path = os.path.join(folder, "envmap.xml")
    with open(path, "w") as f:
        f.write(ENVMAP_XML.format(res=resolution))
    return path


# --objects milk and cloud: a floor under an area light, with what stands on it, as a Mitsuba
# XML file both renderers load. milk: jgi's milk_ball (a backlit rough glass ball holding a
# bounded medium, the sphere's interior)
STAGE_XML = """<scene version="3.0.0">
  <integrator type="volpath"><integer name="max_depth" value="8"/>
    <integer name="rr_depth" value="5"/></integrator>
  <sensor type="perspective"><float name="fov" value="40"/><string name="fov_axis" value="x"/>
    <transform name="to_world"><lookat origin="0, 0.6, 4" target="0, 0, 0" up="0, 1, 0"/>
    </transform>
    <film type="hdrfilm"><integer name="width" value="{res}"/>
      <integer name="height" value="{res}"/><rfilter type="box"/></film>
  </sensor>
  <shape type="rectangle"><transform name="to_world"><scale value="4"/>
    <rotate x="1" angle="-90"/><translate y="-0.8"/></transform>
    <bsdf type="diffuse"><rgb name="reflectance" value="0.5, 0.5, 0.5"/></bsdf></shape>
  <shape type="rectangle"><transform name="to_world"><scale x="4" y="3"/>
    <translate y="2.2" z="-2"/></transform>
    <emitter type="area"><rgb name="radiance" value="1, 1, 1"/></emitter></shape>
<!-- objects -->
</scene>
"""
MILK_BALL = """  <shape type="sphere"><float name="radius" value="0.8"/>
    <bsdf type="roughdielectric"><string name="distribution" value="ggx"/>
      <float name="alpha" value="0.2"/><float name="int_ior" value="1.33"/>
      <float name="ext_ior" value="1"/></bsdf>
    <medium type="homogeneous" name="interior">
      <rgb name="sigma_t" value="0.4, 0.6, 1.0"/><float name="scale" value="5"/>
      <float name="albedo" value="0.6"/>
      <phase type="hg"><float name="g" value="0.4"/></phase>
    </medium></shape>"""
MILK_XML = STAGE_XML.replace("<!-- objects -->", MILK_BALL)


def milk_scene_file(resolution: int) -> str:
    """The milk bench scene as a Mitsuba XML file in a temporary folder."""
    import tempfile

    path = os.path.join(tempfile.mkdtemp(prefix="bench_milk_"), "milk.xml")
    with open(path, "w") as f:
        f.write(MILK_XML.format(res=resolution))
    return path


# --objects cloud: a density grid (a .vol blob written here, zero on its faces) in a turned
# null cube under the same light, as a Mitsuba XML file both load: jgi's grid in a frame of
# its own (spectral tracking against the majorant grid), Mitsuba's heterogeneous medium
CLOUD_XML = STAGE_XML.replace("<!-- objects -->", """  <shape type="cube">
    <transform name="to_world">{cube}</transform>
    <bsdf type="null"/>
    <medium type="heterogeneous" name="interior">
      <volume name="sigma_t" type="gridvolume"><string name="filename" value="cloud.vol"/>
        <transform name="to_world"><scale value="2"/><translate value="-1, -1, -1"/>{cube}
        </transform></volume>
      <rgb name="albedo" value="0.9, 0.85, 0.8"/><float name="scale" value="6"/>
      <phase type="hg"><float name="g" value="0.3"/></phase>
    </medium></shape>""")
CLOUD_CUBE = '<scale value="0.9, 0.6, 0.7"/><rotate y="1" angle="30"/><translate y="0.1"/>'


def cloud_scene_file(resolution: int) -> str:
    """The cloud bench scene (and its 32^3 .vol grid) in a temporary folder."""
    import tempfile

    from jgi.scene.importers.volgrid import write_vol

    folder = tempfile.mkdtemp(prefix="bench_cloud_")
    z, y, x = np.meshgrid(*(np.linspace(-1, 1, 32),) * 3, indexing="ij")
    blob = np.exp(-3.0 * (x**2 + 1.5 * y**2 + z**2)) * (1.0 + 0.3 * np.sin(6 * x) * np.cos(5 * z))
    blob[[0, -1]], blob[:, [0, -1]], blob[:, :, [0, -1]] = 0.0, 0.0, 0.0
    write_vol(os.path.join(folder, "cloud.vol"), blob.astype(np.float32))
    path = os.path.join(folder, "cloud.xml")
    with open(path, "w") as f:
        f.write(CLOUD_XML.format(res=resolution, cube=CLOUD_CUBE))
    return path


def bench_jgi(resolution: int, spp: int, repeats: int, objects: str = "blocks") -> dict:
    import jax

    import jgi

    if objects == "veach_ggx":
        scene = jgi.scenes.veach_plates_ggx(resolution=resolution)
    elif objects == "envmap":
        from jgi.scene.importers.mitsuba import load_mitsuba_xml

        scene = load_mitsuba_xml(envmap_scene_file(resolution))
    elif objects == "fog":
        scene = jgi.load_scene("cornell_box_fog", resolution=resolution)
    elif objects in ("milk", "cloud"):
        from jgi.scene.importers.mitsuba import load_mitsuba_xml

        scene = load_mitsuba_xml(milk_scene_file(resolution) if objects == "milk"
                                 else cloud_scene_file(resolution))
    elif objects == "spheres":
        from jgi.scene import SceneBuilder
        from jgi.scene.builtin import cornell_room

        b = SceneBuilder("cornell_spheres")
        cornell_room(b, resolution)
        for centre, radius in SPHERES:
            b.sphere(centre, radius, "white")
        scene = b.build()
    else:
        scene = jgi.load_scene("cornell_box", resolution=resolution)
    t0 = time.perf_counter()
    jgi.render(scene, "pt", spp=1, seed=0, max_depth=8, rr_depth=5)
    compile_s = time.perf_counter() - t0
    times, cpu, img = [], [], None
    for r in range(repeats):
        t0, c0 = time.perf_counter(), time.process_time()
        img = jgi.render(scene, "pt", spp=spp, seed=1 + r, max_depth=8, rr_depth=5)
        times.append(time.perf_counter() - t0)
        cpu.append(time.process_time() - c0)
    best = min(times)
    n = resolution * resolution * spp
    return dict(name="jgi", mpaths_per_s=n / best / 1e6, seconds=best, compile_s=compile_s,
                mpaths_per_cpu_s=n / min(cpu) / 1e6, mean_rgb=img.reshape(-1, 3).mean(0).tolist(),
                devices=[str(d) for d in jax.devices()])


def bench_mitsuba(resolution: int, spp: int, repeats: int, objects: str = "blocks") -> dict | None:
    if "DRJIT_LIBLLVM_PATH" not in os.environ:
        found = sorted(glob.glob("/usr/lib/*/libLLVM.so.19.1"))
        if found:
            os.environ["DRJIT_LIBLLVM_PATH"] = found[0]
    if not os.environ.get("DRJIT_LIBLLVM_PATH", "").endswith(".so.19.1"):
        # An older LLVM aborts the whole process inside Mitsuba (not an exception we can catch).
        print("mitsuba skipped: libLLVM.so.19.1 not found (apt-get install libllvm19)",
              file=sys.stderr)
        return None
    try:
        import mitsuba as mi
        mi.set_variant("llvm_ad_rgb")
    except Exception as e:  # not installed, or no usable LLVM
        print(f"mitsuba unavailable: {e}", file=sys.stderr)
        return None
    desc = mi.cornell_box()
    if objects == "envmap":
        scene = mi.load_file(envmap_scene_file(resolution))
    elif objects == "milk":
        scene = mi.load_file(milk_scene_file(resolution))
    elif objects == "cloud":
        scene = mi.load_file(cloud_scene_file(resolution))
    elif objects == "veach_ggx":
        from experiments.mitsuba_scene import to_mitsuba
        from jgi.scene import builtin

        desc = to_mitsuba(builtin.veach_plates_builder(resolution, builtin.VEACH_GGX_ALPHAS), mi)
    elif objects == "spheres":
        del desc["small-box"], desc["large-box"]
        for i, (centre, radius) in enumerate(SPHERES):
            desc[f"sphere-{i}"] = {"type": "sphere", "center": list(centre), "radius": radius,
                                   "bsdf": {"type": "ref", "id": "white"}}
    if objects not in ("envmap", "milk", "cloud"):
        desc["sensor"]["film"]["width"] = desc["sensor"]["film"]["height"] = resolution
        desc["sensor"]["film"]["rfilter"] = {"type": "box"}
        desc["integrator"] = {"type": "path", "max_depth": 8, "rr_depth": 5}
    if objects == "fog":   # cornell_box_fog's defaults, filling the room from the sensor
        desc["sensor"]["medium"] = {"type": "homogeneous", "sigma_t": 0.6, "albedo": 0.8,
                                    "phase": {"type": "isotropic"}}
        desc["integrator"] = {"type": "volpath", "max_depth": 8, "rr_depth": 5}
    if objects not in ("envmap", "milk", "cloud"):
        scene = mi.load_dict(desc)
    t0 = time.perf_counter()
    np.asarray(mi.render(scene, spp=1, seed=0))
    compile_s = time.perf_counter() - t0
    times, cpu, img = [], [], None
    for r in range(repeats):
        t0, c0 = time.perf_counter(), time.process_time()
        img = np.asarray(mi.render(scene, spp=spp, seed=1 + r))
        times.append(time.perf_counter() - t0)
        cpu.append(time.process_time() - c0)
    best = min(times)
    n = resolution * resolution * spp
    return dict(name="mitsuba3 llvm_ad_rgb", mpaths_per_s=n / best / 1e6, seconds=best,
                compile_s=compile_s, mpaths_per_cpu_s=n / min(cpu) / 1e6,
                mean_rgb=img.reshape(-1, 3).mean(0).tolist())


def main(argv=None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--spp", type=int, default=64)
    ap.add_argument("--resolution", type=int, default=256)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--devices", type=int, default=1,
                    help="split jgi's lanes over this many virtual CPU devices")
    ap.add_argument("--no-mitsuba", action="store_true")
    ap.add_argument("--objects", choices=("blocks", "spheres", "veach_ggx", "envmap", "fog",
                                          "milk", "cloud"),
                    default="blocks",
                    help="what stands in the room: the two blocks, or two diffuse spheres; or "
                         "Veach's plates with GGX plates instead of the room; or two balls "
                         "under an environment map; or the box filled with fog; or a "
                         "backlit glass ball holding a medium (bounded by the sphere); or a "
                         "density grid in a turned null cube")
    ap.add_argument("--json", default=None)
    a = ap.parse_args(argv)
    if a.devices > 1:
        if "jax" in sys.modules:
            sys.exit("--devices must be set before JAX is imported")
        os.environ["XLA_FLAGS"] = (os.environ.get("XLA_FLAGS", "") +
                                   f" --xla_force_host_platform_device_count={a.devices}").strip()
    print(f"load average {os.getloadavg()[0]:.2f} on {os.cpu_count()} CPUs", file=sys.stderr)
    out = {"jgi": bench_jgi(a.resolution, a.spp, a.repeats, a.objects)}
    if not a.no_mitsuba:
        out["mitsuba"] = bench_mitsuba(a.resolution, a.spp, a.repeats, a.objects)
    for r in out.values():
        if r:
            print(f"{r['name']:24s} {r['mpaths_per_s']:8.2f} Mpaths/s  "
                  f"({r['mpaths_per_cpu_s']:.2f} per CPU-s; {r['seconds']:.2f} s render, "
                  f"{r['compile_s']:.1f} s first call)  "
                  f"mean rgb {np.round(r['mean_rgb'], 4).tolist()}")
    if out.get("mitsuba"):
        out["ratio"] = out["jgi"]["mpaths_per_s"] / out["mitsuba"]["mpaths_per_s"]
        print(f"jgi / Mitsuba 3 throughput: {out['ratio']:.2f}x")
    if a.json:
        with open(a.json, "w") as f:
            json.dump(out, f, indent=2)
    return out


if __name__ == "__main__":
    main()
