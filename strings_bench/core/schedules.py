"""Schedule scales of the run schedules (bench/schedules.py), and how an iteration is labelled (7000 -> 7K).

Every iteration number of a method (checkpoints, densification window, resets, LR schedules) is
multiplied by the preset's steps_scale; intervals keep at least strategies.base.MIN_SCALED_INTERVAL
steps. Measured on 2 CPU cores (synthetic scenes, 320x240; see README and docs/engine.md):
- cpu (0.05: 150/350/1 500 steps for 3K/7K/30K, synthetic360-cpu/storeroom) is the default run: the
  CPU regime of docs/synthetic.md on a frozen room-scale scene where 3DGS reads late, as on the paper's
  captures, in about 10 minutes (README, "What the default run shows");
- early (0.15: 450/1 050 steps for 3K/7K, synthetic/extinguisher), the default before: the paper's
  "readable early" checkpoints on an easy object-centred scene where 3DGS reads early
  (docs/ocr.md, "The default run");
- quick (0.01: 70/300 steps for 7K/30K) runs all five synthetic scenes, two methods, in about 10
  minutes, but text stays illegible (every CER ~1.0): the pipeline end to end, not a comparison;
- standard (0.05: 350/1500 steps) gives visibly sharper text, at several minutes per method and scene;
- paper (1.0) is the paper's 30K schedule (hours per scene on a CPU; meant for a GPU).
"""

SCHEDULE_SCALES: dict[str, float] = {
    "paper": 1.0,
    "standard": 0.05,
    "cpu": 0.05,
    "early": 0.15,
    "quick": 0.01,
    "tiny": 0.005,
}


def iteration_label(iteration: int) -> str:
    """How a paper iteration is named everywhere (tables, results.csv, `methods show`): 7000 -> '7K',
    30000 -> '30K', 350 -> '350'."""
    return f"{iteration // 1000}K" if iteration >= 1000 and iteration % 1000 == 0 else str(iteration)
