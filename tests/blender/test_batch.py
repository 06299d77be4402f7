"""scripts/ovrad_batch.py and `blender -c ovrad`, each documented command run through scripts/blender."""

from __future__ import annotations

import hashlib
import json
import shutil
from pathlib import Path

import pytest

import blender_env

pytestmark = pytest.mark.blender

ROOT = Path(__file__).resolve().parents[2]
CORNELL = blender_env.cornell_blend()  # scenes/cornell.blend, or rebuilt where unreadable
BATCH = ROOT / "scripts" / "ovrad_batch.py"
SMALL = ["--patch-count", "200"]
MESHES = ["Floor", "Ceiling", "BackWall", "LeftWall", "RightWall", "ShortBlock", "TallBlock", "Light"]

# Prints, for every mesh of the open file, its colour attributes as name:domain:type:count.
SHOW_ATTRIBUTES = (
    "import bpy; print('ATTRS', {o.name: sorted(f'{a.name}:{a.domain}:{a.data_type}:{len(a.data)}' "
    "for a in o.data.color_attributes) for o in bpy.data.objects if o.type == 'MESH' "
    "and 'ovrad_source' not in o}); print('IMAGES', sorted(i.name for i in bpy.data.images))"
)


def batch(run_blender, blend, *args, env=None):
    """The documented command: blender -b scene.blend -P scripts/ovrad_batch.py -- [options]."""
    return run_blender(["-b", str(blend), "-P", str(BATCH), "--", *map(str, args)], env=env, timeout=300)


def digest(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def inspect(run_blender, blend: Path) -> tuple[dict, list]:
    proc = run_blender(["-b", str(blend), "--python-exit-code", "1", "--python-expr", SHOW_ATTRIBUTES])
    assert proc.returncode == 0, proc.stderr
    line = next(ln for ln in proc.stdout.splitlines() if ln.startswith("ATTRS "))
    images = next(ln for ln in proc.stdout.splitlines() if ln.startswith("IMAGES "))
    return eval(line[6:]), eval(images[7:])  # noqa: S307  (our own repr of dicts of strings)


def one_error_line(proc) -> str:
    """The process failed with exactly one line of its own on stderr; returns that line."""
    assert proc.returncode != 0, proc.stdout
    lines = [ln for ln in proc.stderr.splitlines() if ln.strip()]
    assert len(lines) == 1 and "Traceback" not in proc.stderr, proc.stderr
    assert lines[0].startswith("ovrad: error: "), lines
    return lines[0]


@pytest.mark.versions
def test_vertex_bake_saves_attributes_report_and_picture(ovrad, run_blender, tmp_path):
    before = digest(CORNELL)
    out, report, picture = tmp_path / "out" / "baked.blend", tmp_path / "r.json", tmp_path / "p.png"
    proc = batch(run_blender, CORNELL, *SMALL, "--output", out, "--report", report, "--picture", picture,
                 "--picture-size", 48, "--picture-samples", 1)  # fmt: skip
    assert proc.returncode == 0, proc.stderr
    assert digest(CORNELL) == before  # the input is never touched
    r = json.loads(report.read_text())
    assert r["ovrad"] == blender_env.module_name()  # the installed extension did the work
    assert r["receivers"] == MESHES and 150 <= r["patches"] <= 300
    assert r["rays"] > 100_000 and 0 <= r["unshot_fraction"] <= r["tolerance"] == pytest.approx(1e-3)
    assert r["solver"] == "exact" and r["beta"] == "smooth" and r["converged"] is True
    assert set(r["seconds"]) == {"generate", "solve", "bake", "save", "picture", "total"}
    # the solve's stages: C kept by Generate for every patch, not integrated again
    assert set(r["solve_seconds"]) == {"index", "overlap", "transport"}
    assert r["overlaps_kept"] == r["patches"]
    # peak resident memory per stage, MiB: Blender itself is resident during each of them
    assert set(r["peak_memory_mb"]) == set(r["seconds"]) - {"total"}
    assert set(r["solve_peak_memory_mb"]) == {"index", "overlap", "transport"}
    assert all(50 < v < 24_000 for v in [*r["peak_memory_mb"].values(), *r["solve_peak_memory_mb"].values()])
    assert r["peak_memory_mb"]["solve"] >= max(r["solve_peak_memory_mb"].values())
    assert 0 < r["transport_escaped"] < r["transport_rays"]  # the box is open at the front
    assert r["output"] == str(out) and r["input"] == str(CORNELL)
    assert picture.stat().st_size > 1000
    attrs, _ = inspect(run_blender, out)
    for name in MESHES:
        (attr,) = attrs[name]
        assert attr.startswith("ovrad_radiance:POINT:FLOAT_COLOR:")
    assert f"ovrad: {r['patches']} patches" in proc.stdout


def test_options_reach_atlas_solve_and_bake(ovrad, run_blender, tmp_path):
    out, report = tmp_path / "o.blend", tmp_path / "r.json"
    proc = batch(run_blender, CORNELL, "--patch-size", "0.12", "--overlap", "1.5", "--beta", "box",
                 "--solver", "exact", "--tolerance", "0.01", "--attribute", "light", "--domain", "CORNER",
                 "--quantity", "irradiance", "--min-rays", "0", "--rays-per-point", "8", "--max-rays",
                 "60000", "--cluster-angle", "0.5", "--output", out, "--report", report)  # fmt: skip
    assert proc.returncode == 0, proc.stderr
    r = json.loads(report.read_text())
    assert (r["beta"], r["solver"], r["overlap"], r["quantity"]) == ("box", "exact", 1.5, "irradiance")
    assert r["rays"] < 1_000_000  # no 4.2 M-ray floor: 8 rays per point, plus the shadow rays
    # ... and at most 60 000 transport rays: fewer rays per point (the shadow rays come on top)
    assert r["max_rays"] == 60_000 and 15_000 <= r["transport_rays"] <= 60_000
    assert r["cluster_angle"] == 0.5
    assert r["tolerance"] == pytest.approx(0.01) and r["unshot_fraction"] <= 0.01
    assert 120 <= r["patches"] <= 260  # 0.12 m patches on about 1.9 m^2
    attrs, _ = inspect(run_blender, out)
    assert attrs["Floor"][0].startswith("light:CORNER:FLOAT_COLOR:")


def test_quality_sets_its_level_and_the_expert_options_override_it(ovrad, run_blender, tmp_path):
    report = tmp_path / "r.json"
    proc = batch(run_blender, CORNELL, "--quality", "draft", *SMALL, "--gather-rays", "8",
                 "--output", tmp_path / "o.blend", "--report", report)  # fmt: skip
    assert proc.returncode == 0, proc.stderr
    r = json.loads(report.read_text())
    draft = ovrad.operators.properties.QUALITY["DRAFT"]
    assert (r["gather_rays"], r["min_rays"], r["quality"]) == (8, draft["min_rays"], "custom")
    assert 150 <= r["patches"] <= 300  # --patch-count 200, not the draft level's
    proc = batch(run_blender, CORNELL, "--quality", "draft", "--output", tmp_path / "d.blend",
                 "--report", report)  # fmt: skip
    assert proc.returncode == 0, proc.stderr
    r = json.loads(report.read_text())
    assert (r["gather_rays"], r["min_rays"], r["quality"]) == (
        draft["gather_rays"],
        draft["min_rays"],
        "draft",
    )


def test_refine_passes_refine_the_atlas_and_solve_it_again(ovrad, run_blender, tmp_path):
    out, report = tmp_path / "r.blend", tmp_path / "r.json"
    proc = batch(run_blender, CORNELL, *SMALL, "--refine", 1, "--output", out, "--report", report)
    assert proc.returncode == 0, proc.stderr
    r = json.loads(report.read_text())
    assert {"generate", "solve", "refine1", "solve2", "bake"} <= set(r["seconds"])
    first = int(proc.stdout.split("ovrad: ")[1].split(" patches on")[0].replace(",", ""))  # Generate's line
    assert r["patches"] > first and r["converged"] is True
    assert r["overlaps_kept"] == r["patches"]  # the refined atlas's C, kept by Refine Atlas


def test_the_papers_solver_can_be_chosen(ovrad, run_blender, tmp_path):
    report = tmp_path / "r.json"
    proc = batch(run_blender, CORNELL, *SMALL, "--solver", "paper", "--output", tmp_path / "o.blend",
                 "--report", report)  # fmt: skip
    assert proc.returncode == 0, proc.stderr
    r = json.loads(report.read_text())
    assert r["solver"] == "paper" and r["converged"] is True


def test_named_receivers_only_get_atlases_and_bakes(ovrad, run_blender, tmp_path):
    out, report = tmp_path / "o.blend", tmp_path / "r.json"
    proc = batch(run_blender, CORNELL, "--patch-count", "100", "--receivers", "Floor,BackWall", "Light",
                 "--output", out, "--report", report)  # fmt: skip
    assert proc.returncode == 0, proc.stderr
    r = json.loads(report.read_text())
    assert r["receivers"] == ["Floor", "BackWall", "Light"] and 60 <= r["patches"] <= 140
    attrs, _ = inspect(run_blender, out)
    assert attrs["Floor"][0].startswith("ovrad_radiance:POINT:") and attrs["Ceiling"] == []


def uv_scene(run_blender, tmp_path) -> Path:
    """The Cornell box with a planar UV map on its floor, saved to tmp_path."""
    path = tmp_path / "uv.blend"
    code = (
        "import bpy; o = bpy.data.objects['Floor']; m = o.data; uv = m.uv_layers.new(name='UVMap'); "
        "co = [v.co for v in m.vertices]; lo = [min(c[i] for c in co) for i in (0, 1)]; "
        "hi = [max(c[i] for c in co) for i in (0, 1)]; "
        "[setattr(uv.data[l.index], 'uv', tuple((co[l.vertex_index][i] - lo[i]) / (hi[i] - lo[i]) "
        "for i in (0, 1))) for l in m.loops]; "
        f"bpy.ops.wm.save_as_mainfile(filepath={str(path)!r})"
    )
    proc = run_blender(["-b", str(CORNELL), "--python-exit-code", "1", "--python-expr", code])
    assert proc.returncode == 0, proc.stderr
    return path


@pytest.mark.versions
def test_image_target_writes_exr_next_to_the_output(ovrad, run_blender, tmp_path):
    src = uv_scene(run_blender, tmp_path)
    out, report = tmp_path / "img" / "o.blend", tmp_path / "r.json"
    proc = batch(run_blender, src, *SMALL, "--target", "image", "--uv", "UVMap", "--size", "32",
                 "--output", out, "--report", report)  # fmt: skip
    assert proc.returncode == 0, proc.stderr
    r = json.loads(report.read_text())
    exr = tmp_path / "img" / "ovrad" / "Floor.exr"
    entry = dict(object="Floor", path=str(exr), uv_map="UVMap", size=32, format="OPEN_EXR", exposure=None)
    entry["image"] = "Floor_ovrad"
    assert r["images"] == [entry] and exr.stat().st_size > 1000
    assert [n["object"] for n in r["not_baked"]] == [m for m in MESHES if m != "Floor"]
    assert "'Ceiling' not baked to an image: 'Ceiling' has no UV map" in proc.stdout
    _, images = inspect(run_blender, out)
    assert images == ["Floor_ovrad"]


def test_image_target_with_defaults_bakes_every_receiver_through_made_uv_maps(ovrad, run_blender, tmp_path):
    out, report = tmp_path / "o.blend", tmp_path / "r.json"
    proc = batch(run_blender, CORNELL, *SMALL, "--target", "image", "--texel-density", "60",
                 "--format", "png16", "--output", out, "--report", report)  # fmt: skip
    assert proc.returncode == 0, proc.stderr
    r = json.loads(report.read_text())
    assert sorted(e["object"] for e in r["images"]) == sorted(MESHES) and r["not_baked"] == []
    for e in r["images"]:
        assert e["uv_map"] == "ovrad_lightmap" and e["format"] == "PNG" and isinstance(e["exposure"], int)
        assert e["path"] == str(tmp_path / "ovrad" / f"{e['object']}.png") and Path(e["path"]).is_file()
        assert e["size"] % 4 == 0 and 4 <= e["size"] <= 4096


def test_in_place_overwrites_only_when_asked(ovrad, run_blender, tmp_path):
    src = tmp_path / "scene.blend"
    shutil.copy(CORNELL, src)
    before = digest(src)
    refused = batch(run_blender, src, *SMALL, "--output", src)
    assert "refusing to overwrite the input file" in one_error_line(refused)
    assert digest(src) == before
    proc = batch(run_blender, src, *SMALL, "--in-place")
    assert proc.returncode == 0, proc.stderr
    attrs, _ = inspect(run_blender, src)
    assert attrs["Floor"][0].startswith("ovrad_radiance:POINT:")


@pytest.mark.parametrize(
    "args, message",
    [
        (["--output", "{tmp}/o.blend", "--bogus", "3"], "unrecognized arguments: --bogus 3"),
        (["--output", "{tmp}/o.blend", "--receivers", "Floor,Nope"], "no object named 'Nope'"),
        (["--output", "{tmp}/o.blend", "--receivers", "Camera"], "'Camera' is not a mesh (camera)"),
        (["--output", "{tmp}/o.blend", "--beta", "wide"], "argument --beta: invalid choice: 'wide'"),
        (["--output", "{tmp}/o.blend", "--tolerance", "2"], "--tolerance must be between 0 and 1"),
        (["--output", "{tmp}/o.blend", "--overlap", "9"], "--overlap must be between 1 and 4"),
        (["--output", "{tmp}/o.blend", "--refine", "9"], "--refine must be between 0 and 4 passes"),
        (["--output", "{tmp}/o.blend", "--min-rays", "-5"], "--min-rays must be between 0 and"),
        (["--output", "{tmp}/o.blend", "--max-rays", "-1"], "--max-rays must be between 0 and"),
        (["--output", "{tmp}/o.blend", "--cluster-angle", "3"], "--cluster-angle must be between 0 and 2"),
        (["--output", "{tmp}/o.blend", "--gather-rays", "-1"], "--gather-rays must be at least 0"),
        (["--output", "{tmp}/o.blend", "--gather-rays", "99999"], "--gather-rays must be between 0 and"),
        (["--output", "{tmp}/o.blend", "--quality", "best"], "argument --quality: invalid choice: 'best'"),
        (["--output", "{tmp}/o.blend", "--in-place"], "--output and --in-place exclude each other"),
        ([], "nothing would be saved: give --output"),
        (["--output", "{tmp}/o.txt"], "--output must be a .blend file"),
        (["--output", "{tmp}/afile/o.blend"], "cannot write the output"),
        (["--output", "{tmp}/o.blend", "--target", "image", "--uv", "Nope"], "'Floor' has no UV map"),
        (["--output", "{tmp}/o.blend", "--texel-density", "0"], "--texel-density must be positive"),
        (["--output", "{tmp}/o.blend", "--max-size", "2"], "--max-size must be between 4 and 16384"),
        (["--output", "{tmp}/o.blend", "--format", "jpg"], "argument --format: invalid choice: 'jpg'"),
    ],
)
def test_bad_input_gives_one_clear_line(ovrad, run_blender, tmp_path, args, message):
    (tmp_path / "afile").write_text("not a folder")
    proc = batch(run_blender, CORNELL, *SMALL, *(a.replace("{tmp}", str(tmp_path)) for a in args))
    assert message in one_error_line(proc)
    assert not (tmp_path / "o.blend").exists()


def test_without_a_file_open(ovrad, run_blender, tmp_path):
    proc = run_blender(["-b", "-P", str(BATCH), "--", "--output", str(tmp_path / "o.blend")])
    assert "no .blend file is open" in one_error_line(proc)


@pytest.mark.versions
def test_blender_c_ovrad_runs_the_same_batch(ovrad, run_blender, tmp_path):
    out, report = tmp_path / "c.blend", tmp_path / "r.json"
    cmd = ["-c", "ovrad", "--input", str(CORNELL), *SMALL, "--output", str(out), "--report", str(report)]
    proc = run_blender(cmd)
    assert proc.returncode == 0, proc.stderr
    r = json.loads(report.read_text())
    assert r["input"] == str(CORNELL) and r["patches"] > 100 and r["rays"] > 0
    attrs, _ = inspect(run_blender, out)
    assert attrs["Floor"][0].startswith("ovrad_radiance:POINT:")
    bad = run_blender(["-c", "ovrad", "--input", str(CORNELL), "--frobnicate"])
    assert "unrecognized arguments: --frobnicate" in one_error_line(bad)
    helped = run_blender(["-c", "ovrad", "--help"])
    assert helped.returncode == 0 and "--patch-count" in helped.stdout


def test_batch_runs_from_a_checkout_without_the_extension(run_blender, tmp_path):
    user = tmp_path / "user"
    env = {"BLENDER_USER_RESOURCES": str(user)}
    env |= {var: str(user / sub) for var, sub in blender_env.USER_DIRS.items()}
    report = tmp_path / "r.json"
    proc = batch(run_blender, CORNELL, *SMALL, "--output", tmp_path / "o.blend", "--report", report, env=env)
    assert proc.returncode == 0, proc.stderr
    assert json.loads(report.read_text())["ovrad"] == "ovrad"


@pytest.mark.versions
def test_the_copy_shipped_inside_the_extension_runs(ovrad, run_blender, tmp_path):
    shipped = Path(ovrad.__file__).parent / "scripts" / "ovrad_batch.py"
    assert shipped.is_file()
    report = tmp_path / "r.json"
    proc = run_blender(["-b", str(CORNELL), "-P", str(shipped), "--", *SMALL, "--output",
                        str(tmp_path / "o.blend"), "--report", str(report)])  # fmt: skip
    assert proc.returncode == 0, proc.stderr
    assert json.loads(report.read_text())["ovrad"] == blender_env.module_name()
