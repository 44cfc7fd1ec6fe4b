"""Scoring a student's work against the truth: `icefloe score map` and `icefloe score path`.

* `maths`: alignment (Umeyama: rigid or similarity), map RMSE, trajectory ATE and RPE; numpy only.
* `inputs`: landmark maps (ECE4078's slam.txt, icefloe's own) and trajectories (CSV, recordings,
  bus samples) as plain arrays, with one-line errors naming the file or key.

The verbs are in ``icefloe/cli/score.py``; docs/score.md is the guide.
"""
