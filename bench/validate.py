"""Time and memory of ``pv.diagnose`` on many LiDAR scans with a hidden effect (issue 25, section 3).

    python bench/validate.py [scans] [effect=value ...]     e.g. 100000 scale=1.02, 100000 yaw_deg=2

The scans come from tests/hidden_world.py (the square loop, 21 rays, noise 0.01 m). Prints the
wall and CPU seconds of ``diagnose`` and the process's peak resident memory, then the diagnosis.
"""

import resource
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))

import hidden_world  # noqa: E402

import percver as pv  # noqa: E402


def main(argv):
    scans = int(argv[0]) if argv else 100_000
    hidden = {k: float(v) for k, v in (a.split("=") for a in argv[1:])} or {"scale": 1.02}
    poses = hidden_world.poses(scans, seed=1)
    data = pv.Measurements(poses, hidden_world.scan(poses, seed=2, **hidden), state_names=["x", "y", "theta"])
    wall, cpu = time.time(), time.process_time()
    diagnosis = pv.diagnose(pv.sensors.lidar.canonical(), data)
    wall, cpu = time.time() - wall, time.process_time() - cpu
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    print(f"{scans} scans, hidden {hidden}: diagnose {wall:.1f} s wall, {cpu:.1f} s CPU, peak memory {peak:.0f} MB")
    print(diagnosis.table())


if __name__ == "__main__":
    main(sys.argv[1:])
