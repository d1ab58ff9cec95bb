"""Compile the meniscus, run the probe scenario with noisy markers, plot estimate, truth, ±2σ.

    python python/examples/meniscus_probe.py [--out meniscus_probe.png] [--no-plot]

The scenario is models/meniscus/scenario_report.toml: the probe presses down (-z) with 0.5 N,
ramped in over 0.2 s, then held until 0.4 s (400 steps of 1 ms).

The "truth" here is SYNTHETIC: the compiled model itself run open loop with the known probe
force (no measurements). The markers are that truth plus Gaussian noise of the scene's σ
(0.2 mm), fixed seed. The filter then runs with the same known force and the noisy markers.
So the plot shows how the filter weighs noisy markers against its model and what its ±2σ band
claims, not the model's error against the full-order co-rotational FEM (for that, see
`crokf-verify report` and models/meniscus/verification/).

matplotlib is optional: without it (or with --no-plot) the script prints the figures only.
"""

import argparse
import pathlib
import sys

import numpy as np

import crokf

try:
    import tomllib
except ImportError:  # Python < 3.11
    import tomli as tomllib

REPO = pathlib.Path(__file__).resolve().parents[2]
MENISCUS = REPO / "models" / "meniscus"


def probe_force(scenario, times):
    """World-frame probe force at each time (linear interpolation, held after the last point), N."""
    load = next(l for l in scenario["load"] if l["name"] == "probe")
    t = np.asarray(load["times"], dtype=float)
    f = np.asarray(load["forces"], dtype=float)
    return np.stack([np.interp(times, t, f[:, c]) for c in range(3)], axis=1)


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", default="meniscus_probe.png", help="plot file (PNG)")
    parser.add_argument("--no-plot", action="store_true", help="print the figures only")
    parser.add_argument("--seed", type=int, default=1)
    args = parser.parse_args(argv)

    model, report = crokf.compile(MENISCUS / "scene.toml", report=False)
    print(f"compiled: r = {model.order}, Δt = {model.dt * 1e3:.1f} ms, "
          f"{len(model.measurement_channels)} marker channels, {report['total_seconds']:.2f} s")

    scenario = tomllib.loads((MENISCUS / "scenario_report.toml").read_text())
    steps = int(round(scenario["duration"] / model.dt))
    times = np.arange(1, steps + 1) * model.dt
    inputs = np.zeros((steps, len(model.inputs)))
    force = probe_force(scenario, times)
    for c, axis in enumerate("xyz"):
        inputs[:, model.inputs.index(f"probe.{axis}")] = force[:, c]

    # Synthetic truth (see the module docstring) and noisy markers from it.
    truth = crokf.Estimator(model).run(inputs)
    noise_std = np.sqrt(model.measurement_variance)
    rng = np.random.default_rng(args.seed)
    markers = truth["measurements"] + noise_std * rng.standard_normal(truth["measurements"].shape)

    estimate = crokf.Estimator(model).run(inputs, markers)

    sensor = model.sensors.index("near_probe")
    z = 2
    channel = model.measurement_channels.index("near_probe.z")
    est_z = estimate["sensors"][:, sensor, z]
    std_z = estimate["sensor_std"][:, sensor, z]
    true_z = truth["sensors"][:, sensor, z]
    err = est_z - true_z
    inside = np.mean(np.abs(err) <= 2 * std_z)
    print(f"near_probe.z at {times[-1]:.3f} s: truth {true_z[-1] * 1e3:.3f} mm, "
          f"estimate {est_z[-1] * 1e3:.3f} mm ± {2 * std_z[-1] * 1e3:.3f} mm (2σ)")
    print(f"near_probe.z RMS error: estimate {np.sqrt(np.mean(err ** 2)) * 1e3:.4f} mm, "
          f"raw marker {np.sqrt(np.mean((markers[:, channel] - true_z) ** 2)) * 1e3:.4f} mm; "
          f"|error| <= 2σ at {inside * 100:.0f} % of the steps")

    if args.no_plot:
        return 0
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        print("matplotlib is not installed: no plot (pip install matplotlib)")
        return 0
    fig, ax = plt.subplots(figsize=(8, 4.5))
    ms = 1e3
    ax.plot(times, markers[:, channel] * ms, ".", ms=2, color="0.6", label="marker (truth + noise)")
    ax.fill_between(times, (est_z - 2 * std_z) * ms, (est_z + 2 * std_z) * ms, color="C0", alpha=0.25,
                    label="estimate ± 2σ")
    ax.plot(times, est_z * ms, color="C0", label="estimate")
    ax.plot(times, true_z * ms, "--", color="C3", label="truth (synthetic, open loop)")
    ax.set_xlabel("time, s")
    ax.set_ylabel("near_probe marker, z displacement, mm")
    ax.set_title("meniscus under the probe (0.5 N ramped over 0.2 s)")
    ax.legend(loc="lower left")
    fig.tight_layout()
    fig.savefig(args.out, dpi=120)
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
