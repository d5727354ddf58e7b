"""Validate the canonical F1/10 LiDAR model against "real" runs, find what it misses, fix it.

The real runs are simulated here: the scanner is mounted turned by 2.5 degrees, two metallic
wall panels mirror away rays that hit them at grazing incidence, and ranges are noisy. The
canonical model knows none of this. percver shows where the model fails (near the panels),
names both effects with their parameters, and the error falls step by step.

    python examples/validate_lidar.py [report-directory]
"""

import sys

import percver as pv
from percver.sensors import lidar
from percver.validate import effects

out = sys.argv[1] if len(sys.argv) > 1 else "validate-lidar-report"
track = lidar.square_track(width=1.5, length=20)
model = lidar.canonical(track, lidar.Lidar.f1tenth21())

# ---- the "real" world: what the car's scanner actually does (unknown to the modeller)
panels = [((6.0, 20.0), (10.0, 20.0), 45.0), ((20.0, 7.0), (20.0, 4.0), 35.0)]  # wall ends, threshold deg
real = model.with_effect(effects.get("angle_offset", yaw_deg=2.5))
for a, b, threshold in panels:
    start, end = sorted((track.wall_position(*a), track.wall_position(*b)))
    real = real.with_effect(effects.get("specular_reflection", start=start, end=end, threshold_deg=threshold))
real = real.with_effect(effects.get("gaussian_noise", sigma=0.01))
poses = track.sample_poses(1200, seed=1)
data = pv.Measurements(poses, real.sample(poses, rng=2), state_names=model.state_names, measurement_names=lidar.Lidar.f1tenth21())

# ---- validation: how wrong is the canonical model, and where?
report = pv.compare(model, data)
print(f"canonical model: RMSE {report.error:.3f} m over {len(data)} scans\n")
print(report.where().table(rows=4), "\n")

# ---- the whole loop: name effects, add them, refit, until nothing helps
diagnosis = pv.diagnose(model, data, progress=True)
print(diagnosis.rankings[0].table(), "\n")
print(diagnosis.table(), "\n")
for effect in diagnosis.final_model.effects:
    if effect.name == "specular_reflection":
        (x0, x1), (y0, y1) = track.wall_point([effect.params["start"], effect.params["end"]])
        print(
            f"reflective panel from ({x0:.2f}, {y0:.2f}) to ({x1:.2f}, {y1:.2f}), beyond {effect.params['threshold_deg']:.1f} deg incidence"
        )
print(f"\nreport: {diagnosis.to_html(out)}")
