"""Parameters (issue 8): every integer has an upper bound the kernels can honour, checked where it is read.

``methods.params.resolve`` checks method parameters and, through ``api.resolve_settings``,
the common settings (spp, image size, seed, threads) with the bounds of ``caustica.limits``.
No render runs here: resolving settings compiles nothing.
"""
from __future__ import annotations

import pytest

import caustica
from caustica import limits, memory, methods
from caustica.api import COMMON_PARAMS, resolve_settings
from caustica.errors import ParameterError, SceneError
from caustica.methods.params import Param, positive, resolve

SCENE = "cornell-diacaustic"


@pytest.fixture(scope="module")
def scene():
    return caustica.load_scene(SCENE)


def _int_params():
    """(method, Param) of every integer parameter of every method."""
    return [(name, p) for name, cls in sorted(methods.available().items()) for p in cls.params if p.type is int]


def test_an_int_param_without_max_gets_the_32_bit_bound():
    spec = (Param("n", int, 1, "a count", positive, ">= 1"),)
    assert resolve("m", spec, {"n": limits.INT_MAX})["n"] == limits.INT_MAX
    with pytest.raises(ParameterError, match=r"--n: 2147483648 is out of range; allowed: >= 1 and <= 2,147,483,647"):
        resolve("m", spec, {"n": limits.INT_MAX + 1})


def test_max_of_a_param_is_inclusive_and_named_in_the_message():
    spec = (Param("light_samples", int, 5, "n", positive, ">= 1", max=64),)
    assert resolve("m", spec, {"light_samples": 64})["light_samples"] == 64
    with pytest.raises(ParameterError, match=r"--light-samples: 65 .*<= 64"):
        resolve("m", spec, {"light_samples": 65})


@pytest.mark.parametrize("method, spec", _int_params(), ids=lambda x: x if isinstance(x, str) else x.name)
def test_every_int_parameter_of_every_method_stops_at_its_bound(method, spec):
    """At the bound it is accepted (also by the other checks), one above it is refused naming the bound."""
    cls = methods.get(method)
    assert spec.upper is not None and spec.upper < 2**63
    assert resolve(method, cls.params, {spec.name: spec.upper})[spec.name] == spec.upper
    with pytest.raises(ParameterError) as info:
        resolve(method, cls.params, {spec.name: spec.upper + 1})
    assert spec.flag in str(info.value) and f"{spec.upper:,}" in str(info.value)


@pytest.mark.parametrize("method, name, bound", [
    ("pm", "light_samples", 64),          # n x n shadow rays and 2 n^2 random dimensions per shading point
    ("spm", "max_specular_depth", 1024),
    ("pm", "max_bounces", 1024),
    ("pt", "max_depth", 1024),            # pt's own cap for "unlimited"
    ("pt", "rr_depth", 1024),
])
def test_bounds_of_the_loop_counts(method, name, bound):
    spec = {p.name: p for p in methods.get(method).params}[name]
    assert spec.upper == bound


@pytest.mark.parametrize("value", [float("inf"), float("-inf"), float("nan")])
def test_float_parameters_must_be_finite(value):
    with pytest.raises(ParameterError, match="--radius"):
        resolve("pm", methods.get("pm").params, {"radius": value})


def test_a_huge_value_is_not_echoed_whole():
    with pytest.raises(ParameterError) as info:
        resolve("pm", methods.get("pm").params, {"k": int("9" * 4000)})
    assert len(str(info.value)) < 200 and "4,000 characters" in str(info.value)


# ----------------------------------------------------------------------------- common settings


@pytest.mark.parametrize("kw, flag", [
    (dict(spp=2**63), "--spp"),                      # rendered black before: the sample index overflowed
    (dict(spp=1e20), "--spp"),                       # reached Numba as a TypingError
    (dict(spp=limits.MAX_SPP + 1), "--spp"),
    (dict(seed=2**64), "--seed"),
    (dict(seed=limits.MAX_SEED + 1), "--seed"),
    (dict(seed=-1), "--seed"),
    (dict(threads=limits.MAX_THREADS + 1), "--threads"),
    (dict(threads=0), "--threads"),
    (dict(res=(limits.INT_MAX + 1, 1)), "--res width"),
    (dict(res=(1, limits.INT_MAX + 1)), "--res height"),
    (dict(res="0x4"), "--res width"),
])
def test_common_settings_out_of_range_are_refused(scene, kw, flag):
    with pytest.raises(ParameterError) as info:
        resolve_settings(scene, "pt", **{"res": 4, **kw})
    assert str(info.value).startswith(flag + ":"), str(info.value)
    assert "allowed" in str(info.value)


def test_a_non_integer_spp_is_refused_not_rounded(scene):
    with pytest.raises(ParameterError, match=r"--spp: '2.5' is not a valid int"):
        resolve_settings(scene, "pt", res=4, spp=2.5)


def test_common_settings_at_their_bounds_are_accepted(scene):
    _, _, s = resolve_settings(scene, "pt", spp=limits.MAX_SPP, res=4, seed=limits.MAX_SEED,
                               threads=limits.MAX_THREADS)
    assert (s["spp"], s["seed"], s["threads"]) == (limits.MAX_SPP, limits.MAX_SEED, limits.MAX_THREADS)
    _, _, s = resolve_settings(scene, "pt", spp=1, res=(100_000, 1))
    assert (s["width"], s["height"]) == (100_000, 1)


def test_an_image_beyond_int32_pixels_is_refused(scene):
    with pytest.raises(ParameterError, match=r"a 50000x50000 image has 2,500,000,000 pixels, more than the "
                                             r"2,147,483,647 \(int32\)"):
        resolve_settings(scene, "pt", spp=1, res=50_000)


def test_the_bounds_keep_a_camera_sample_index_exact():
    """(y * width + x) * spp + s, the key of a camera sample, stays exact in int64 and float64."""
    assert limits.MAX_PIXELS * limits.MAX_SPP <= 2**53
    # a pixel's k-nearest searches (at most 2 per gather, 9 gathers per sample) fit the int32 that counts them
    assert 18 * limits.MAX_SPP < 2**31
    assert {p.name for p in COMMON_PARAMS} == {"spp", "width", "height", "seed", "threads"}


def test_the_scene_loader_and_the_render_settings_share_the_bounds(tmp_path):
    """A sampler at the loader's bound passes the render's checks; one above fails in the loader, with its line."""
    from caustica.scene import xml_loader
    assert xml_loader.MAX_SAMPLE_COUNT == limits.MAX_SPP and xml_loader.MAX_FILM_PIXELS == limits.MAX_PIXELS

    def scene_with(sample_count):
        xml = tmp_path / "sampler.xml"
        xml.write_text('<scene version="3.0.0">\n'
                       '  <sensor type="perspective">\n'
                       '    <float name="fov" value="40"/>\n'
                       '    <sampler type="independent">\n'
                       f'      <integer name="sample_count" value="{sample_count}"/>\n'
                       '    </sampler>\n'
                       '    <film type="hdrfilm"><integer name="width" value="4"/>'
                       '<integer name="height" value="4"/></film>\n'
                       '  </sensor>\n'
                       '  <shape type="rectangle"/>\n'
                       '  <emitter type="point"><point name="position" value="0, 0, 3"/></emitter>\n'
                       '</scene>\n')
        return caustica.load_scene(xml)

    _, _, s = resolve_settings(scene_with(limits.MAX_SPP), "pt")
    assert s["spp"] == limits.MAX_SPP
    with pytest.raises(SceneError, match=r"sampler.xml:5"):
        scene_with(limits.MAX_SPP + 1)


# ----------------------------------------------------------------------------- per-thread scratch memory


def test_k_nearest_scratch_is_checked_against_memory_before_rendering(scene, monkeypatch):
    """--k sizes two arrays per worker thread (index + distance, 16 bytes per neighbour)."""
    monkeypatch.setattr(memory, "physical_memory_bytes", lambda: 10 * 2**30)   # a 10 GiB machine: 6 GiB budget
    _, _, s = resolve_settings(scene, "spm", res=4, threads=4, k=10_000_000)   # 0.64 GB: fine
    assert s["k"] == 10_000_000
    with pytest.raises(ParameterError) as info:
        resolve_settings(scene, "spm", res=4, threads=4, k=200_000_000)        # 12.8 GB
    msg = str(info.value)
    assert "--k 200,000,000 on 4 threads" in msg and "12.8 GB" in msg and "lower --k or --threads" in msg
    with pytest.raises(ParameterError, match="--caustic-k"):
        resolve_settings(scene, "pm", res=4, threads=4, caustic_k=200_000_000)


def test_the_image_memory_check_counts_each_method_s_own_arrays(scene, monkeypatch):
    """A progressive method keeps float64 pixel statistics: about twice the bytes per pixel of pt."""
    monkeypatch.setattr(memory, "physical_memory_bytes", lambda: 2**30)   # 1 GiB: a 0.64 GB budget
    _, _, s = resolve_settings(scene, "pt", res=2000, spp=1)               # 2000^2 x 112 bytes = 0.45 GB
    assert s["width"] == 2000
    with pytest.raises(ParameterError, match=r"a 2000x2000 image would need about 1\.4 GB"):
        resolve_settings(scene, "sppm", res=2000)                          # 2000^2 x 340 bytes = 1.36 GB


@pytest.mark.parametrize("scene_name, claim", [("cornell-diacaustic", True), ("plastic-caustic.xml", False),
                                               ("plastic-caustic.xml", True), ("cornell-diacaustic-fog", False)])
def test_the_camera_pass_holds_what_its_memory_estimate_counts(scene_name, claim):
    """camera_pass_bytes, which the memory checks add per pixel, is exactly what a camera pass allocates: the whole
    BSDF rows where roughplastic's split points need them (the caustic photons' own statistics), the medium segments
    in a scene with media."""
    from pathlib import Path
    from caustica.photons.visible_points import VISIBLE_POINT_BYTES, camera_pass, camera_pass_bytes
    path = Path(__file__).parent / "scenes" / scene_name
    scene_ = caustica.load_scene(str(path) if path.exists() else scene_name)
    _, _, settings = resolve_settings(scene_, "sppm", res=6, multi_pass=True, threads=1)
    points, segments, _ = camera_pass(scene_, settings, 0, claim=claim)
    held = sum(a.nbytes for a in points) + (sum(a.nbytes for a in segments) if segments is not None else 0)
    assert held == 36 * camera_pass_bytes(scene_, claim)
    rows = scene_name == "plastic-caustic.xml" and claim
    assert (camera_pass_bytes(scene_, claim) > VISIBLE_POINT_BYTES) == (rows or scene_.has_media)


def test_a_camera_pass_checks_what_it_allocates_before_allocating(monkeypatch):
    """The camera pass refuses, before allocating, visible points (and medium segments) that would not fit: the
    estimate is camera_pass_bytes a pixel, the same the methods' checks count."""
    from caustica.photons.visible_points import camera_pass, camera_pass_bytes
    fog = caustica.load_scene("cornell-diacaustic-fog")
    _, _, settings = resolve_settings(fog, "sppm", res=64, multi_pass=True, threads=1)
    need = 64 * 64 * camera_pass_bytes(fog, False)
    monkeypatch.setattr(memory, "physical_memory_bytes", lambda: int(0.9 * need / memory.BUDGET_FRACTION))
    with pytest.raises(ParameterError, match=r"a camera pass of 4,096 pixels \(visible points and \d+ medium "
                                             r"segments each\) would need about"):
        camera_pass(fog, settings, 0)


def test_pm_in_media_frees_each_sample_s_camera_pass_before_the_next():
    """pm's camera pass in media runs one progressive camera pass per sample; a sample's visible points and medium
    segments (camera_pass_bytes a pixel, about 1.2 kB in the fog box) must be freed before the next sample allocates
    its own, as the memory check counts one sample's.  Until 2026-12-06 two were alive at once: the peak of 4
    samples was one sample's arrays above that of 1."""
    import tracemalloc
    from caustica.photons.visible_points import camera_pass_bytes
    fog = caustica.load_scene("cornell-diacaustic-fog")
    kw = dict(res=48, seed=0, threads=2, photons=2000)
    caustica.render(fog, "pm", spp=1, **kw)   # compiles (or loads) the kernels
    peaks = []
    for spp in (1, 4):
        tracemalloc.start()
        try:
            caustica.render(fog, "pm", spp=spp, **kw)
            peaks.append(tracemalloc.get_traced_memory()[1])
        finally:
            tracemalloc.stop()
    assert peaks[1] - peaks[0] < 0.25 * 48 * 48 * camera_pass_bytes(fog, False), peaks


def test_resolved_settings_are_read_by_attribute_and_cannot_change(scene):
    """What resolve_settings returns is a typed, read-only structure: a misspelt name is an error that names
    the nearest setting, not a KeyError or a silent None."""
    _, _, settings = resolve_settings(scene, "sppm", res=16, seed=3, alpha=0.5)
    assert (settings.alpha, settings.width, settings.seed, settings.caustic_radius) == (0.5, 16, 3, None)
    assert isinstance(settings.alpha, float) and isinstance(settings.width, int)
    with pytest.raises(AttributeError, match=r"method 'sppm' has no setting 'alhpa' \(did you mean 'alpha'\?\)"):
        settings.alhpa
    with pytest.raises(AttributeError, match="read-only"):
        settings.alpha = 0.3
    with pytest.raises(TypeError):
        settings["alpha"] = 0.3
    one_thread = settings.replace(threads=1)
    assert one_thread.threads == 1
    assert dict(one_thread, threads=settings.threads) == dict(settings)   # only threads changed
    with pytest.raises(AttributeError, match="did you mean 'threads'"):
        settings.replace(thread=1)


def test_settings_survive_pickling_and_json(scene):
    """Dask tasks pickle the settings; sidecars and checkpoints write them as JSON."""
    import json
    import pickle
    _, _, settings = resolve_settings(scene, "pspm", res=8, streams=100)
    back = pickle.loads(pickle.dumps(settings))
    assert back == settings and back.streams == 100 and type(back) is type(settings)
    assert json.loads(json.dumps(dict(settings))) == dict(settings)
    from caustica.imageio import to_jsonable
    assert to_jsonable({"settings": settings}) == {"settings": json.loads(json.dumps(dict(settings)))}
    assert "streams" in dir(settings)
