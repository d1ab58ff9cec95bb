"""The example script runs end to end (with the Agg backend when matplotlib is present)."""

import os
import pathlib
import subprocess
import sys

EXAMPLE = pathlib.Path(__file__).resolve().parents[1] / "examples" / "meniscus_probe.py"


def test_meniscus_probe_example(tmp_path):
    out = tmp_path / "probe.png"
    env = dict(os.environ, MPLBACKEND="Agg")
    run = subprocess.run([sys.executable, str(EXAMPLE), "--out", str(out)], capture_output=True,
                         text=True, env=env, timeout=600)
    assert run.returncode == 0, run.stderr
    assert "near_probe.z RMS error" in run.stdout
    # The filtered estimate must beat the raw markers (the filter averages the noise).
    line = next(l for l in run.stdout.splitlines() if "RMS error" in l)
    est = float(line.split("estimate ")[1].split(" mm")[0])
    raw = float(line.split("raw marker ")[1].split(" mm")[0])
    assert est < raw
    try:
        import matplotlib  # noqa: F401
    except ImportError:
        return
    assert out.stat().st_size > 10_000
