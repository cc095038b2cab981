"""Experiments (issue 5): the metrics, ``caustica compare`` and ``caustica experiment all --quick`` end to end."""
from __future__ import annotations

import csv
import math
import json
import subprocess
import sys

import numpy as np
import pytest

from caustica import imageio
from caustica.cli import main
from caustica.experiments import metrics as M
from caustica.experiments.reference import noise_stats
from caustica.experiments.config import ABLATION, ABLATION_SCENES, CONFIGS, EQUAL_METRIC, FLOOR_LABEL
from caustica.experiments.statistics import equal_comparison


def _image(seed=0, shape=(32, 40)):
    rng = np.random.default_rng(seed)
    return (0.05 + rng.random((*shape, 3))).astype(np.float64)


# --------------------------------------------------------------------------- metrics


def test_identical_images_have_no_error():
    r = _image()
    m = M.all_metrics(r, r, r[:, :, 0] > 0.5)
    for key in ("rel_mse", "block_err", "mean_err", "flip", "caustic_rel_mse", "caustic_block_err",
                "caustic_mean_err", "caustic_flip"):
        assert m[key] == pytest.approx(0.0, abs=1e-12), key
    assert m["ssim"] == pytest.approx(1.0)
    assert m["caustic_ssim"] == pytest.approx(1.0)


def test_rel_mse_of_a_known_perturbation():
    r = _image(1)
    t = r * 1.1
    expected = np.mean((0.1 * r) ** 2 / (r ** 2 + M.REL_EPS))
    assert M.rel_mse(t, r) == pytest.approx(expected, rel=1e-12)
    # a constant image: the formula in closed form
    c = np.full((8, 8, 3), 0.5)
    assert M.rel_mse(c + 0.1, c) == pytest.approx(0.01 / (0.25 + M.REL_EPS))


def test_block_err_of_a_scaled_image_is_the_scale():
    r = _image(2)
    assert M.block_err(r * 1.2, r) == pytest.approx(0.2)
    # zero-mean noise inside each tile averages out: the block error stays far below the pixel error
    rng = np.random.default_rng(3)
    flat = np.full((64, 64, 3), 0.5)
    noisy = flat + rng.normal(0, 0.05, flat.shape)
    assert M.block_err(noisy, flat, block=8) < 0.3 * np.sqrt(M.rel_mse(noisy, flat) * (0.25 + M.REL_EPS) / 0.25)


def test_mean_err_is_the_signed_energy_difference():
    r = _image(5)
    assert M.mean_err(r * 0.99, r) == pytest.approx(-0.01)
    assert M.mean_err(r * 1.25, r) == pytest.approx(0.25)
    # zero-mean noise leaves the mean (nearly) alone while the block error sees it
    rng = np.random.default_rng(6)
    flat = np.full((64, 64, 3), 0.5)
    noisy = flat + rng.normal(0, 0.05, flat.shape)
    assert abs(M.mean_err(noisy, flat)) < 4 * 0.05 / 0.5 / np.sqrt(flat.size)
    mask = np.zeros((64, 64), bool)
    mask[:8] = True
    t = flat.copy()
    t[:8] *= 2.0
    assert M.mean_err(t, flat, mask) == pytest.approx(1.0)
    assert M.mean_err(t, flat, ~mask) == pytest.approx(0.0)


def test_seed_statistics_are_mean_and_sample_sd():
    from caustica.experiments.statistics import seed_statistics
    from caustica.experiments.tables import _cell
    st = seed_statistics([{"caustic_block_err": 0.1, "ssim": 0.5}, {"caustic_block_err": 0.3, "ssim": 0.7}])
    assert st["caustic_block_err"] == pytest.approx(0.2)
    assert st["caustic_block_err_sd"] == pytest.approx(np.std([0.1, 0.3], ddof=1))
    assert st["ssim_sd"] == pytest.approx(np.std([0.5, 0.7], ddof=1))
    assert _cell(st, "caustic_block_err") == "0.2 ± 0.14"       # block errors are shown with their spread
    assert _cell(st, "ssim") == "0.6"
    one = seed_statistics([{"caustic_block_err": 0.1}])
    assert one["caustic_block_err"] == 0.1 and np.isnan(one["caustic_block_err_sd"])
    assert _cell(one, "caustic_block_err") == "0.1"


def test_paired_differences_cancel_noise_shared_by_both_rows():
    from caustica.experiments.statistics import paired, seed_statistics
    rng = np.random.default_rng(7)
    common = rng.normal(0.0, 0.1, 5)                  # e.g. the camera pass's noise, the same for both rows
    a = seed_statistics([{"e": 0.30 + c} for c in common])
    b = seed_statistics([{"e": 0.25 + c + 1e-3 * x} for c, x in zip(common, rng.normal(size=5))])
    mean, se, z = paired(a, b, "e")
    assert mean == pytest.approx(0.05, abs=5e-3)
    assert se < 1e-3 < a["e_sd"]                       # the common noise is gone from the difference
    assert z > 20
    assert paired(a, seed_statistics([{"e": 0.1}]), "e") is None     # different seed counts: no pairing


def test_mask_restricts_every_metric():
    r = _image(4)
    t = r.copy()
    mask = np.zeros(r.shape[:2], bool)
    mask[:16] = True
    t[16:] *= 3.0             # error only outside the mask
    m = M.all_metrics(t, r, mask)
    assert m["caustic_rel_mse"] == pytest.approx(0.0, abs=1e-12)
    assert m["caustic_block_err"] == pytest.approx(0.0, abs=1e-12)
    assert m["rel_mse"] > 0.1
    t2 = r.copy()
    t2[:16] *= 3.0            # error only inside the mask
    expected = np.mean(((2 * r[:16]) ** 2) / (r[:16] ** 2 + M.REL_EPS))
    assert M.rel_mse(t2, r, mask) == pytest.approx(expected)
    assert M.ssim(t2, r, mask) < M.ssim(t2, r, ~mask)
    assert M.flip(t2, r, mask) > M.flip(t2, r, ~mask)


def test_metrics_refuse_images_of_different_sizes():
    with pytest.raises(Exception, match="differ in size"):
        M.rel_mse(np.zeros((4, 4, 3)), np.zeros((5, 4, 3)))


def test_noise_of_two_halves():
    rng = np.random.default_rng(5)
    truth = np.full((64, 64, 3), 1.0)
    a = truth + rng.normal(0, 0.1, truth.shape)
    b = truth + rng.normal(0, 0.1, truth.shape)
    n = noise_stats(a, b)
    # each half has relative sd 0.1 (eps is small next to 1): the mean of the halves 0.1 / sqrt(2)
    assert n["est_rel_rmse_of_full"] == pytest.approx(0.1 / np.sqrt(2), rel=0.05)


def test_equal_time_and_equal_error_interpolation():
    # time = 1 + budget, error = 0.1 / budget (SPM) and 0.2 / budget (PM+C): PM+C needs twice SPM's budget
    def rows(scale):
        return [{"budget_factor": b, "time_s": 1.0 + b, EQUAL_METRIC: scale / b} for b in (0.5, 1, 2, 4)]
    eq = equal_comparison({"SPM": rows(0.1), "PM+C": rows(0.2)}, "SPM")
    assert eq["SPM"]["equal_error_time_s"] == pytest.approx(2.0)
    assert eq["PM+C"]["equal_error_time_s"] == pytest.approx(3.0)
    assert eq["PM+C"]["equal_time_error"] == pytest.approx(0.2)
    assert not eq["PM+C"]["equal_error_extrapolated"]


# --------------------------------------------------------------------------- caustica compare


def test_compare_prints_metrics(tmp_path, capsys):
    r = _image(6).astype(np.float32)
    imageio.write_exr(tmp_path / "ref.exr", r)
    imageio.write_exr(tmp_path / "test.exr", r * 1.1)
    mask = np.zeros(r.shape, np.float32)
    mask[:10] = 1.0
    imageio.write_png(tmp_path / "mask.png", mask)
    assert main(["compare", str(tmp_path / "test.exr"), str(tmp_path / "ref.exr"),
                 "--mask", str(tmp_path / "mask.png")]) == 0
    out = capsys.readouterr().out
    for word in ("relMSE", "block err", "mean err", "SSIM", "FLIP", "whole", "mask"):
        assert word in out
    whole = out.splitlines()[1].split()
    assert float(whole[1]) == pytest.approx(M.rel_mse(r * 1.1, r), rel=1e-4)
    assert float(whole[2]) == pytest.approx(0.1, rel=1e-4)
    assert float(whole[3]) == pytest.approx(0.1, rel=1e-4)      # mean err: 10 % too bright


@pytest.mark.parametrize("bad", ["missing", "size", "mask"])
def test_compare_bad_input_is_one_line_exit_2(tmp_path, bad):
    r = _image(7).astype(np.float32)
    imageio.write_exr(tmp_path / "ref.exr", r)
    imageio.write_exr(tmp_path / "small.exr", r[:8, :8])
    args = [str(tmp_path / "ref.exr"), str(tmp_path / "ref.exr")]
    if bad == "missing":
        args[0] = str(tmp_path / "nope.exr")
    elif bad == "size":
        args[0] = str(tmp_path / "small.exr")
    else:
        args += ["--mask", str(tmp_path / "nope.png")]
    proc = subprocess.run([sys.executable, "-m", "caustica", "compare", *args], check=False,
                          capture_output=True, text=True)
    assert proc.returncode == 2
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("caustica: error:")


def test_experiment_bad_name_is_exit_2(tmp_path, capsys):
    assert main(["experiment", "table7", "-o", str(tmp_path / "x"), "--quick", "-q"]) == 2
    assert "table7" in capsys.readouterr().err
    assert not (tmp_path / "x").exists()


# --------------------------------------------------------------------------- the caustic mask

def test_the_mask_is_not_traced_with_pm_c_s_own_caustic_photons():
    """The mask of an experiment with seed s must not be PM+C's caustic map at seed s (issue 8):
    its photons come from their own stream, so the two splats differ photon for photon while
    showing the same caustic."""
    import caustica
    from caustica.api import progress_factory, resolve_settings
    from caustica.experiments.masks import caustic_density
    from caustica.methods.pm import PhotonMapping
    from caustica.photon_view import splat_records
    scene = caustica.load_scene("cornell-diacaustic")
    n, w, seed = 20_000, 32, 4
    mask_img = caustic_density(scene, w, w, photons=n, seed=seed, threads=1)
    scene, _, settings = resolve_settings(scene, "pm", res=(w, w), seed=seed, threads=1, photons=1, caustic_photons=n)
    _, cmap, _, _ = PhotonMapping.build_maps(scene, settings, progress_factory(False))
    pmc = np.zeros((w, w, 3))
    splat_records(scene.geometry, scene.materials, scene.camera(w, w), np.ascontiguousarray(cmap.position),
                  np.ascontiguousarray(cmap.power), pmc)
    pmc = pmc.sum(axis=2)
    assert mask_img.sum() > 0 and pmc.sum() > 0
    assert not np.array_equal(mask_img, pmc)
    assert np.abs(mask_img - pmc).sum() > 0.05 * pmc.sum()          # not a rounding difference
    assert np.corrcoef(mask_img.ravel(), pmc.ravel())[0, 1] > 0.9   # but the same caustic


def test_stream_tags_never_share_keys_for_nearby_seeds():
    """path_key(seed, tag, i) mixes seed * G + tag: two tags give the same key only for seeds that
    differ by (tag_a - tag_b) / G mod 2^64.  Every pair of tags must need a difference above 2^40,
    so no two renders or masks of any experiment (seeds s .. s + 1001) ever share random numbers."""
    from caustica.sampling import rng
    tags = {k: v for k, v in vars(rng).items() if k.startswith("STREAM_")}
    assert "STREAM_CAUSTIC_MASK" in tags
    assert len(set(tags.values())) == len(tags), tags
    mod = 1 << 64
    g_inv = pow(int(rng._GOLDEN), -1, mod)
    for a in tags.values():
        for b in tags.values():
            if a != b:
                delta = ((a - b) * g_inv) % mod
                assert min(delta, mod - delta) > 1 << 40, (a, b)
    # the mask's tag against every phase of the first 4096 passes of a progressive render
    mask = rng.STREAM_CAUSTIC_MASK
    for phase in (v for k, v in tags.items() if k != "STREAM_CAUSTIC_MASK"):
        for k in range(4096):
            b = rng.pass_stream(phase, k)
            assert b != mask
            delta = ((mask - b) * g_inv) % mod
            assert min(delta, mod - delta) > 1 << 40, (phase, k)


# --------------------------------------------------------------------------- the whole pipeline


def _csv(path):
    with open(path, newline="", encoding="utf-8") as fh:
        return list(csv.DictReader(fh))


def test_experiment_all_quick_end_to_end(tmp_path):
    out = tmp_path / "exp"
    assert main(["experiment", "all", "--quick", "-o", str(out), "--cache-dir", str(tmp_path / "cache"),
                 "--threads", "2", "-q"]) == 0

    t1 = _csv(out / "table1" / "table1.csv")
    assert len(t1) == 27 + 1                   # the sweep and the reference's noise row
    assert t1[0]["label"].startswith("reference noise")
    assert {(r["streams"], r["assoc"], r["stream_radius"]) for r in t1[1:]} == {
        (str(s), str(a), str(float(rs))) for s in (1000, 5000, 10000) for a in (10, 50, 100) for rs in (0.1, 2.5, 5)}
    for col in ("photons_emitted", "time_s", "map_mb", "rel_mse", "caustic_rel_mse", "caustic_ssim",
                "caustic_flip", "caustic_block_err"):
        assert all(r[col] != "" for r in t1[1:]), col
    assert (out / "table1" / "fig4_error_vs_streams.png").stat().st_size > 1000
    assert "| configuration |" in (out / "table1" / "table1.md").read_text()

    for name in ("table2", "table3"):
        rows = _csv(out / name / f"{name}.csv")
        assert [r["label"] for r in rows[:3]] == list(CONFIGS)
        assert rows[3]["label"] == FLOOR_LABEL                    # the truncation floor: PM with mr = 64
        assert rows[4]["label"].startswith("reference noise")
        assert rows[3]["photons_emitted"] == rows[1]["photons_emitted"]
        assert all(r["mean_err"] != "" and r["seeds"] == "1" for r in rows[:4])
        for col in ("photons_emitted", "map_mb", "time_s", "caustic_rel_mse", "equal_error_time_s",
                    "equal_time_error", "time_to_pmc_error_s"):
            assert col in rows[0]
        assert float(rows[2]["photons_emitted"]) == 200_000      # PM+C: 100,000 + 100,000
        assert len(_csv(out / name / f"{name}_budget_sweep.csv")) == 3 * 3
        md = (out / name / f"{name}.md").read_text()
        assert "PM+C" in md and "caustic relMSE" in md and "caustic block err in SPM's time" in md
        assert FLOOR_LABEL in md and "mean err" in md
        assert (out / name / f"{name}_error_vs_time.png").is_file()

    for name, scene in (("fig5", "cornell-pyramid"), ("fig8", "cornell-diacaustic"),
                        ("fig9", "cornell-catacaustic")):
        assert (out / name / f"{name}_{scene}.png").stat().st_size > 1000
    for scene in ABLATION_SCENES:
        rows = _csv(out / "merge-ablation" / f"merge_ablation_{scene}.csv")
        assert [r["label"] for r in rows[:-1]] == [a[0] for a in ABLATION]
        assert rows[-1]["label"].startswith("reference noise")
        assert all(r["caustic_block_err"] != "" for r in rows[:-1])
        assert (out / "merge-ablation" / f"{scene}_caustic_mask.png").is_file()
    fig6 = json.loads((out / "fig6" / "results.json").read_text())
    assert fig6.get("skipped") or (out / "fig6" / "fig6_cornell-bunny.png").is_file()

    report = (out / "report.md").read_text()
    for text in ("Table 1", "Table 2", "Table 3", "Figure 5", "Figure 8", "Figure 9", "reference noise",
                 "table1/fig4_error_vs_streams.png", "Equal error", "relMSE", "Truncation floor",
                 "Merge ablation", "PM with 10,000 photons"):
        assert text in report, text
    # the reference is cached: a second run of one experiment renders no new reference
    cached = list((tmp_path / "cache").iterdir())
    assert len(cached) == 2


def test_seeds_give_every_error_a_spread(tmp_path):
    """--seeds 2: each measured configuration is rendered with seeds s and s + 1; the row holds the mean
    and the s.d. of the two, and the Markdown shows block errors as mean ± s.d."""
    out = tmp_path / "exp"
    assert main(["experiment", "table3", "--quick", "--res", "16", "--seeds", "2", "--seed", "5", "-o", str(out),
                 "--cache-dir", str(tmp_path / "cache"), "--threads", "1", "-q"]) == 0
    rows = _csv(out / "table3" / "table3.csv")
    for r in rows[:4]:
        assert r["seeds"] == "2"
        assert float(r["caustic_block_err_sd"]) > 0 and float(r["block_err_sd"]) > 0   # two seeds, two images
    assert "±" in (out / "table3" / "table3.md").read_text()
    res = json.loads((out / "table3" / "results.json").read_text())
    assert res["settings"]["seeds"] == [5, 6]
    assert "seeds 5..6" in (out / "report.md").read_text()


@pytest.mark.parametrize("seeds", ["0", "101"])
def test_bad_seed_count_is_refused_before_anything_is_written(tmp_path, capsys, seeds):
    assert main(["experiment", "table2", "--quick", "--seeds", seeds, "-o", str(tmp_path / "x"), "-q"]) == 2
    assert "--seeds" in capsys.readouterr().err
    assert not (tmp_path / "x").exists()


def test_user_reference_checks_size_and_reads_noise(tmp_path):
    from caustica.errors import CausticaError
    from caustica.experiments.reference import user_reference
    r = _image(8, (16, 16)).astype(np.float32)
    imageio.write_exr(tmp_path / "ref.exr", r)
    with pytest.raises(CausticaError, match="--res 16"):
        user_reference(tmp_path / "ref.exr", 32, 32)
    assert not user_reference(tmp_path / "ref.exr", 16, 16).noise          # unknown noise
    imageio.write_json(tmp_path / "ref.json", {"noise": {"est_rel_rmse_of_full": 0.02}})
    ref = user_reference(tmp_path / "ref.exr", 16, 16)
    assert ref.noise["est_rel_rmse_of_full"] == 0.02
    assert "0.0200" in ref.noise_line()


def test_one_reference_file_for_several_scenes_is_refused(tmp_path, capsys):
    r = _image(9, (16, 16)).astype(np.float32)
    imageio.write_exr(tmp_path / "ref.exr", r)
    assert main(["experiment", "table2", "table3", "--quick", "-q", "-o", str(tmp_path / "o"),
                 "--reference", str(tmp_path / "ref.exr")]) == 2
    assert "SCENE=PATH" in capsys.readouterr().err


def test_rel_rmse_is_the_norm_relative_rmse():
    from caustica.experiments.convergence import rel_rmse
    ref = np.ones((4, 4, 3))
    test = ref.copy()
    test[0, 0] = 3.0                      # one pixel off by 2 in all channels: sqrt(3*4 / 48)
    assert rel_rmse(test, ref) == pytest.approx(math.sqrt(12 / 48))
    mask = np.zeros((4, 4), bool)
    mask[0, :2] = True
    assert rel_rmse(test, ref, mask) == pytest.approx(math.sqrt(12 / 6))
    assert math.isnan(rel_rmse(test, np.zeros_like(ref)))


def test_convergence_experiment_end_to_end(tmp_path, monkeypatch):
    """A cut-down study (one scene, two methods, one budget): every method's timed render keeps to
    its budget, is measured on the whole image and the mask, and the summary names the winner."""
    import json
    from caustica.experiments import convergence, runner
    monkeypatch.setattr(convergence, "SCENES", ("cornell-diacaustic",))
    monkeypatch.setattr(convergence, "PROGRESSIVE", (("pt", "pt", {}), ("SPPM", "sppm", {})))
    monkeypatch.setattr(convergence, "QUICK_BUDGETS_S", (0.4,))
    monkeypatch.setattr(convergence, "QUICK_PMC_PHOTONS", (2000,))
    cfg = runner.Config(out=tmp_path / "exp", quick=True, res=24, progress=False)
    res = runner.run(["convergence"], cfg)["convergence"]
    rows = res["rows"]
    timed = [r for r in rows if r["budget_s"] is not None]
    assert {r["label"] for r in timed} >= {"pt", "SPPM"}
    for r in timed:
        assert r["time_s"] <= 0.4 + 2.0, r          # the last pass may end past the budget by its own length
        for key in ("rel_rmse", "caustic_rel_rmse", "caustic_block_err", "flip"):
            assert math.isfinite(r[key]) and r[key] >= 0, (r["label"], key)
    assert any(r["label"].startswith("PM+C") for r in rows)
    # the pt reference is two halves: its own noise in the same measure is known
    (floor,) = [r for r in rows if r["method"] == "reference"]
    assert 0 < floor["caustic_rel_rmse"] < math.inf and 0 < floor["rel_rmse"] < math.inf
    if convergence.mitsuba_module() is not None:
        assert any(r["method"] == "mitsuba" for r in rows)
        assert "Mitsuba 3" in res["summary"]
    assert "cornell-diacaustic at 0.4 s: best caustic relRMSE" in res["summary"]
    folder = tmp_path / "exp" / "convergence"
    assert (folder / "convergence_cornell-diacaustic.png").is_file()
    assert json.loads((folder / "results.json").read_text())["name"] == "convergence"


def test_the_reference_noise_estimated_from_the_peer_renders():
    """A Mitsuba reference of N_ref samples: peer renders of N_b samples measured against it have
    expected relMSE v / N_b + v / N_ref; peer_floor inverts that to the reference's sqrt(v / N_ref)."""
    from caustica.experiments.convergence import peer_floor
    from caustica.experiments.reference import Reference
    ref = Reference(np.zeros((2, 2, 3), np.float32), "refs", spp=32_768, renderer="mitsuba 3.9.1 (scalar_rgb)")
    v_whole, v_caustic = 0.09, 16.0
    rows = [{"passes": n, "rel_rmse": math.sqrt(v_whole / n + v_whole / 32_768),
             "caustic_rel_rmse": math.sqrt(v_caustic / n + v_caustic / 32_768)} for n in (40, 160, 640)]
    got = peer_floor(ref, rows)
    assert got["rel_rmse"] == pytest.approx(math.sqrt(v_whole / 32_768))
    assert got["caustic_rel_rmse"] == pytest.approx(math.sqrt(v_caustic / 32_768))
    # not a Mitsuba render, or its samples unknown: no estimate
    assert peer_floor(Reference(ref.image, "pt", spp=32_768, renderer="caustica pt"), rows)["rel_rmse"] is None
    assert peer_floor(Reference(ref.image, "x"), rows)["caustic_rel_rmse"] is None


# --------------------------------------------------------------------------- hostile input (issue 19)


def _cut_down_convergence(monkeypatch, budget=0.4):
    """The convergence study on one scene, pt and SPPM at one budget, PM+C at one count."""
    from caustica.experiments import convergence
    monkeypatch.setattr(convergence, "SCENES", ("cornell-diacaustic",))
    monkeypatch.setattr(convergence, "PROGRESSIVE", (("pt", "pt", {}), ("SPPM", "sppm", {})))
    monkeypatch.setattr(convergence, "QUICK_BUDGETS_S", (budget,))
    monkeypatch.setattr(convergence, "QUICK_PMC_PHOTONS", (2000,))


def test_ctrl_c_stops_the_convergence_experiment_and_scores_nothing(cli, tmp_path, monkeypatch, interrupt_at_pass):
    """Ctrl-C in a timed render (here: as pt's third pass starts) used to return the two passes finished,
    which the table then scored as the render of the whole budget, and the experiment went on. Now it
    stops the experiment: exit 130, one line, no table written."""
    _cut_down_convergence(monkeypatch, budget=30.0)
    interrupt_at_pass("pt", 2)
    out = tmp_path / "exp"
    code, _, err = cli("experiment", "convergence", "--quick", "--res", "16", "-o", out, "--cache-dir",
                       tmp_path / "cache", "-q")
    assert code == 130, err
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("caustica: interrupted") and "no render cut short" in lines[0]
    assert not (out / "convergence" / "convergence.csv").exists() and not (out / "report.md").exists()


def test_an_interrupted_render_is_never_returned_to_an_experiment(monkeypatch):
    """The one place experiments get their renders from (local and on a worker): a render that reports
    itself interrupted raises KeyboardInterrupt instead of being scored."""
    import caustica
    from caustica.experiments import renders

    class Interrupted:
        stats = {"interrupted": True, "passes": 2}
    monkeypatch.setattr(renders, "render", lambda *a, **k: Interrupted())
    with pytest.raises(KeyboardInterrupt):
        renders.render_job(None, "pt", {"time_s": 5.0}, None, set(), 1)
    assert caustica  # imported for the methods' registry


@pytest.mark.parametrize("make, words", [(lambda: np.zeros((16, 16, 3), np.float32), "every pixel is zero"),
                                         (lambda: np.full((16, 16, 3), np.nan, np.float32), "not finite")])
def test_a_reference_without_light_or_with_nan_is_refused_before_rendering(cli, tmp_path, monkeypatch, make,
                                                                           words):
    """An all-zero reference made every relative error NaN and matplotlib's log axes raise; a NaN one
    likewise: one line, exit 2, before anything is written."""
    _cut_down_convergence(monkeypatch)
    imageio.write_exr(tmp_path / "ref.exr", make())
    out = tmp_path / "exp"
    code, _, err = cli("experiment", "convergence", "--quick", "--res", "16", "-o", out, "--reference",
                       f"cornell-diacaustic={tmp_path / 'ref.exr'}", "-q")
    lines = err.strip().splitlines()
    assert code == 2 and len(lines) == 1 and words in lines[0] and "ref.exr" in lines[0], err
    assert not out.exists()


def test_a_reference_dark_over_the_caustic_mask_is_refused():
    from caustica.errors import CausticaError
    from caustica.experiments.reference import check_reference_image
    img = np.ones((8, 8, 3), np.float32)
    mask = np.zeros((8, 8), bool)
    mask[2:4, 2:4] = True
    check_reference_image(img, "ref", mask)
    img[mask] = 0.0
    with pytest.raises(CausticaError, match=r"every pixel of the caustic mask \(4 pixels\) is zero"):
        check_reference_image(img, "ref", mask)


def test_convergence_plot_leaves_out_undefined_errors(tmp_path):
    """A NaN or zero error has no place on a log axis: the plot leaves it out rather than failing."""
    from caustica.experiments.figures import convergence_plot
    rows = [{"label": "pt", "time_s": 1.0, "rel_rmse": float("nan"), "caustic_rel_rmse": 0.0},
            {"label": "pt", "time_s": 2.0, "rel_rmse": float("nan"), "caustic_rel_rmse": float("nan")},
            {"label": "ref", "method": "reference", "time_s": None, "rel_rmse": float("nan"),
             "caustic_rel_rmse": None}]
    convergence_plot(rows, tmp_path / "c.png", "scene")
    assert (tmp_path / "c.png").stat().st_size > 1000


@pytest.mark.parametrize("reference, words", [
    ("nosuch={ref}", "'nosuch' is not a scene these experiments measure; the scenes measured: cornell-catacaustic"),
    ("cornell-diacaustic={ref}", "'cornell-diacaustic' is not a scene these experiments measure"),
    ("cornell-catacaustic={tmp}/missing.exr", "no such file or folder"),
])
def test_a_reference_for_a_scene_the_run_does_not_measure_is_refused(cli, tmp_path, reference, words):
    """--reference SCENE=PATH for a scene the experiments do not measure was silently ignored (and the
    run measured against caustica's own reference instead). The cache folder given is a file, so
    that before the fix this failed on it, not after a run."""
    imageio.write_exr(tmp_path / "ref.exr", _image(3, (16, 16)).astype(np.float32))
    (tmp_path / "file").write_text("")
    code, _, err = cli("experiment", "table3", "--quick", "--res", "16", "-o", tmp_path / "out", "--cache-dir",
                       tmp_path / "file" / "cache", "--reference",
                       reference.format(ref=tmp_path / "ref.exr", tmp=tmp_path), "-q")
    lines = err.strip().splitlines()
    assert code == 2 and len(lines) == 1 and words in lines[0], err
    assert not (tmp_path / "out").exists()


def test_two_references_for_one_scene_are_refused(cli, tmp_path):
    imageio.write_exr(tmp_path / "ref.exr", _image(3, (16, 16)).astype(np.float32))
    ref = f"cornell-catacaustic={tmp_path / 'ref.exr'}"
    code, _, err = cli("experiment", "table3", "--quick", "--res", "16", "-o", tmp_path / "out",
                       "--reference", ref, "--reference", ref, "-q")
    assert code == 2 and "has a reference already" in err, err
    assert not (tmp_path / "out").exists()


@pytest.mark.parametrize("output", ["", "  "])
def test_an_empty_experiment_output_folder_is_refused(cli, tmp_path, monkeypatch, output):
    """-o '' is Path('') = the working directory: it wrote the experiment's folders there."""
    monkeypatch.chdir(tmp_path)
    (tmp_path / "file").write_text("")
    code, _, err = cli("experiment", "table3", "--quick", "-o", output, "--cache-dir", tmp_path / "file" / "c", "-q")
    assert code == 2 and "-o: the output folder is empty" in err, err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["file"]
