"""What the photon-mapping methods (pm, spm) share: parameters, termination, the camera pass, one-shot passes."""
from __future__ import annotations

import time

import numpy as np

from ..jit import parallel_for
from ..photons.estimate import FILTERS
from ..photons.gather import gather_pixels
from ..photons.trace import TERMINATION_CAP, TERMINATION_ROULETTE
from .params import Param, non_negative, positive

TERMINATIONS = {"cap": TERMINATION_CAP, "roulette": TERMINATION_ROULETTE}

#: Parameters of the radiance estimate and the camera pass (SPEC §2-3), the paper's defaults.
ESTIMATE_PARAMS = (
    Param("max_bounces", int, 4, "diffuse bounces of a photon / leading photon (the paper's mr)",
          positive, ">= 1", max=1024),
    Param("k", int, 100, "photons (stream records) per radiance estimate", positive, ">= 1",
          scratch=16),  # the k-nearest search's index + distance arrays, per thread
    Param("radius", float, 3.0, "maximum search radius R (scene units)", positive, "> 0"),
    Param("filter", str, "none", "radiance-estimate filter kernel", choices=tuple(FILTERS)),
    Param("termination", str, "cap",
          "cap: scale power by the albedo and stop after max_bounces (the paper); "
          "roulette: Russian roulette with the mean albedo", choices=tuple(TERMINATIONS)),
    Param("light_samples", int, 5, "n for n x n stratified shadow rays per area light",
          positive, ">= 1", max=64),
    Param("fixed_light_grid", bool, False,
          "use the n x n grid's cell centres (the paper's 25 point lights) instead of jittered samples"),
    Param("max_specular_depth", int, 16, "mirror/glass bounces of a camera ray", non_negative, ">= 0",
          max=1024),
)


def camera_pass(scene, settings, global_map, caustic_map, k_caustic, r_caustic, progress):
    """Render the image from the maps; returns (image, timings, number of k-nearest searches)."""
    cam = scene.camera(settings["width"], settings["height"])
    image = np.zeros((cam.height, cam.width, 3), np.float32)
    filt = FILTERS[settings["filter"]]

    n = cam.width * cam.height
    knn_queries = np.zeros(n, np.int32)
    bar = progress(total=n, desc="camera pass", unit="px")
    t0 = time.perf_counter()
    compile_s = parallel_for(gather_pixels, n, (scene.geometry, scene.materials, scene.lights, cam, global_map,
                                                caustic_map, settings["seed"], settings["spp"], settings["k"],
                                                settings["radius"], k_caustic, r_caustic, filt,
                                                settings["light_samples"], settings["fixed_light_grid"],
                                                settings["max_specular_depth"], image, knn_queries),
                             threads=settings["threads"], progress=bar)
    bar.close()
    return image, {"compile_s": compile_s, "camera_pass_s": time.perf_counter() - t0 - compile_s}, \
        int(knn_queries.sum())


class OneShotState:
    """The state of a one-shot method: nothing before its one pass, the image after it."""

    def __init__(self, image=None):
        self.image = image

    @property
    def passes(self) -> int:
        return 0 if self.image is None else 1


class OneShot:
    """A method whose whole render is one pass: ``render_once(scene, settings, progress) -> (image, stats)``."""
    progressive = False

    @staticmethod
    def new_state(scene, settings):
        return OneShotState()

    @classmethod
    def run_pass(cls, scene, settings, state, progress):
        image, stats = cls.render_once(scene, settings, progress)
        return OneShotState(image), stats

    @staticmethod
    def image(scene, settings, state):
        return state.image

    @staticmethod
    def final_stats(scene, settings, state):
        return {}
