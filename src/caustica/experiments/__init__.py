"""The paper's experiments, measured against a converged reference (issue 5).

``caustica experiment NAME -o DIR`` runs :func:`runner.run`; ``caustica compare`` uses
:mod:`metrics`.  See docs/experiments.md.
"""
from .metrics import METRICS, all_metrics, block_err, flip, mean_err, rel_mse, ssim
from .config import EXPERIMENTS, Config
from .runner import run

__all__ = ["EXPERIMENTS", "METRICS", "Config", "all_metrics", "block_err", "flip", "mean_err", "rel_mse", "run",
           "ssim"]
