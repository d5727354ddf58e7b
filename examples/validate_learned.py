"""When no physical effect explains the misfit: learn the paper's noise model for it.

The "real" hallway has a box (a bin, 50 cm wide) standing in it that the canonical F1/10 LiDAR
model does not know, and no effect of percver's library stands for. ``diagnose`` reports the
region where the model fails as unexplained; with ``learn=True`` it then trains a knock-out
classifier (torch) on the residual, keeps it only if it lowers the error on held-out scans,
and writes it as ONNX next to the HTML report.

    python examples/validate_learned.py [report-directory]      # needs torch: pip install "percver[train]"
"""

import sys

import numpy as np

import percver as pv
from percver.sensors import lidar
from percver.validate import effects

out = sys.argv[1] if len(sys.argv) > 1 else "validate-learned-report"
track = lidar.square_track(width=1.5, length=20)
model = lidar.canonical(track, lidar.Lidar.f1tenth21())

# ---- the "real" world: the same track plus a 0.5 m box in the north hallway at x = 10 m
x0, x1, y0, y1 = 9.75, 10.25, 19.0, 19.5
box = [[(x0, y0), (x1, y0)], [(x1, y0), (x1, y1)], [(x1, y1), (x0, y1)], [(x0, y1), (x0, y0)]]
real_track = lidar.Track(np.concatenate([track.segments, box]), track.hallways, name="square loop with a box")
real = lidar.canonical(real_track, lidar.Lidar.f1tenth21()).with_effect(effects.get("gaussian_noise", sigma=0.01))
poses = track.sample_poses(3200, seed=1)
poses = poses[~((poses[:, 0] > x0 - 0.3) & (poses[:, 0] < x1 + 0.3) & (poses[:, 1] > y0 - 0.3))]  # not in the box
data = pv.Measurements(poses, real.sample(poses, rng=2), state_names=model.state_names)

# ---- library effects first; then a learned knock-out model for what is left
plain = pv.diagnose(model, data)
print(plain.table(), "\n")
diagnosis = pv.diagnose(model, data, learn=True, progress=True)
print(diagnosis.table(), "\n")
attempt = diagnosis.learned
print(
    f"{attempt.kind} model on {attempt.held_out_rows} held-out scans: RMSE {attempt.held_out_error_before:.3f} -> "
    f"{attempt.held_out_error_after:.3f} m (gain {attempt.gain:.0%}, kept: {attempt.claimed})"
)
print(f"report: {diagnosis.to_html(out)}")
