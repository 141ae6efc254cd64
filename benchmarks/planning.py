"""Planned against random configurations: the calibration error against the simulator's truth versus N.

    .venv/bin/python benchmarks/planning.py --robot robonaut-a --mode full --counts 16 24 32 48 67 --seeds 8
    .venv/bin/python benchmarks/planning.py --robot nao --mode full --counts 36 72 144 --seeds 5
    .venv/bin/python benchmarks/planning.py ... --svg docs/planning-robonaut-a.svg   # also draw the curve

Per seed and N, three ways to choose N configurations, each planned with the nominal model (what a robot
that was never calibrated believes; `--mode daily`: a full calibration of day 1, and the robot of a later day
with drifted joint offsets, as the paper's section IV-B) inside the joint limits less the margin:
- random: what replay's "N new configurations" did before (the simulator's sampling: uniform visible
  configurations; NAO: the paper's stances, 3 head postures each);
- d-optimal: greedy D-optimal selection and exchange from the planner's candidates;
- planned: the planner (`calib plan`): the task-space criterion, the predicted error over the workspace.
"plan s" is the wall time to choose them (candidates, visibility, selection), "cpu s" the process's CPU time
for it (the same on a quiet machine; the wall time grows on a shared one).
Each set is then measured on the true robot (the profile's hidden truth, the sensor's noise: stereo depth
noise growing with z^2), configurations the true robot does not show to the sensor lost as a real
replay loses them, and calibrated with `calibrate` (the defaults of `calib solve`). The error: RMS over
300 held-out visible configurations of the distance between the calibrated model's prediction and the
true robot's (no measurement noise: the calibration's own error), in the measurement's unit.
"predicted" is the planner's own figure before moving (the RMS of the expected error over its workspace,
linearised at the base model, all configurations kept). "expected" is the noise model's figure for the set
as measured: the expected RMS held-out error sqrt(trace(C A)) of a calibration from the frames kept,
linearised at the truth, with A over the same held-out configurations (in daily mode: as if the base
calibration were exact). It has no noise draw in it, so it separates the methods far better than a few
seeds' measured errors do; a measured mean of single draws' RMS comes out below it (E sqrt(x) < sqrt(E x)).
"""

from __future__ import annotations

import argparse
import json
import time

import numpy as np

from calib_core import InputError, SimulatedRobot, calibrate, load_profile
from calib_core.estimation.planning import JOINT_MARGIN_DEG, candidates, design, plan, within_margin
from calib_core.model.profile import Profile
from calib_core.vision.visibility import Visibility

METHODS = {"random": "random", "d": "greedy D-optimal", "task": "planned (task space)"}
COLOURS = {"random": "#888888", "d": "#1f77b4", "task": "#d62728"}


def random_configurations(profile: Profile, p_base: np.ndarray, n: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """The simulator's sampling with the base model, inside the limits less the margin (as replay did)."""
    stances = profile.simulation.get("sampling", {}).get("kind") == "stances"
    for attempt in range(10):  # NAO: whole stances, as the paper took them; a seed may find too few
        try:
            sim = SimulatedRobot(profile, p_base, seed=seed + 1000 * attempt)
            q, targets = sim.configurations(n if stances else 2 * n + 10)
            break
        except InputError:
            continue
    keep = within_margin(profile, q, JOINT_MARGIN_DEG)
    return q[keep][:n], targets[keep][:n]


def predictions(profile: Profile, p: np.ndarray, q: np.ndarray, targets: np.ndarray) -> np.ndarray:
    return SimulatedRobot(profile, p, quantise=False).measure(q, targets).data.measured


def expected_rms(
    profile: Profile, mode: str, truth: np.ndarray, q: np.ndarray, targets: np.ndarray, held: tuple
) -> float:
    """The noise model's expected RMS error over the held-out configurations of a calibration from q, at the
    truth (inf when q do not determine every parameter)."""
    d = design(profile, mode, truth, q, targets, workspace=held)
    return d.predict(d.start(regularise=False) + d.information(np.arange(len(q))), len(q)).rms


Results = dict[str, dict[int, list[float]]]


def run(args: argparse.Namespace) -> tuple[Results, Results]:
    profile = load_profile(args.robot)
    day1 = SimulatedRobot.from_profile(profile, seed=7)
    base, p_base, truth = None, profile.nominal(), profile.true_params()
    if args.mode == "daily":  # the paper's later day: offsets drifted, planned and fitted from a full calibration
        base = calibrate(profile, day1.simulate(67).data, "full")
        p_base, truth = base.params(profile), day1.drifted(seed=2).true_params
    held_q, held_t = candidates(profile, truth, seed=10_000, count=300)
    held = (held_q, held_t)
    true_pred = predictions(profile, truth, held_q, held_t)
    errors: Results = {m: {n: [] for n in args.counts} for m in args.methods}
    expected: Results = {m: {n: [] for n in args.counts} for m in args.methods}
    print(f"{args.robot} {args.mode}: calibration error against the truth, RMS over {len(held_q)} held-out")
    print(
        f"{'N':>5} {'method':22} {'error mean':>11} {'sd':>8} {'kept':>6} {'expected':>9} {'sd':>7} "
        f"{'predicted':>10} {'plan s':>7} {'cpu s':>6}"
    )
    for n in args.counts:
        for method in args.methods:
            kept, predicted, seconds, cpu = [], [], [], []
            for seed in range(args.seeds):
                start, start_cpu = time.perf_counter(), time.process_time()
                if method == "random":
                    q, targets = random_configurations(profile, p_base, n, seed)
                    pred = None
                else:
                    planned = plan(profile, args.mode, n, p_base, seed=seed, criterion=method)
                    q, targets, pred = planned.q, planned.targets, planned.predicted.rms
                seconds.append(time.perf_counter() - start)
                cpu.append(time.process_time() - start_cpu)
                robot = SimulatedRobot.from_profile(profile, seed=1000 + seed, truth=truth)
                seen = Visibility(profile, robot.true_params).sees(q, targets)
                data = robot.measure(q[seen], targets[seen]).data
                cal = calibrate(profile, data, args.mode, base)
                e = predictions(profile, cal.params(profile), held_q, held_t) - true_pred
                errors[method][n].append(float(np.sqrt(np.mean(np.sum(e**2, axis=1)))))
                expected[method][n].append(expected_rms(profile, args.mode, truth, q[seen], targets[seen], held))
                kept.append(int(seen.sum()))
                if pred is not None:
                    predicted.append(pred)
            v, x = errors[method][n], expected[method][n]
            shown = f"{np.mean(predicted):10.4f}" if predicted else f"{'-':>10}"
            print(
                f"{n:5d} {METHODS[method]:22} {np.mean(v):11.4f} {np.std(v):8.4f} {np.mean(kept):6.1f} "
                f"{np.mean(x):9.4f} {np.std(x):7.4f} {shown} {np.mean(seconds):7.2f} {np.mean(cpu):6.2f}",
                flush=True,
            )
    return errors, expected


def svg(
    errors: Results, title: str, unit: str, path: str, ymax: float | None = None, expected: Results | None = None
) -> None:
    """The curves (mean, with the spread over seeds as bars of one standard deviation) as a plain SVG;
    `ymax`: the axis' top, a point above it drawn at the top with its value; `expected`: each method's mean
    expected RMS, dashed."""
    W, H, left, right, top, bottom = 640, 400, 70, 20, 40, 55
    ns = sorted({n for m in errors.values() for n in m})
    peak = ymax or max(np.mean(v) + np.std(v) for m in errors.values() for v in m.values())
    step = 10 ** np.floor(np.log10(peak / 5))
    step *= next(k for k in (1, 2, 5, 10) if peak / (k * step) <= 6)
    hi = step * np.ceil(peak / step)
    lo_n, hi_n = min(ns), max(ns)

    def x(n: float) -> float:
        return left + (n - lo_n) / max(hi_n - lo_n, 1) * (W - left - right)

    def y(e: float) -> float:
        return H - bottom - min(max(e, 0.0), hi) / hi * (H - top - bottom)

    out = [
        f'<svg xmlns="http://www.w3.org/2000/svg" width="{W}" height="{H}" font-family="sans-serif" font-size="12">',
        f'<rect width="{W}" height="{H}" fill="white"/>',
        f'<text x="{W / 2}" y="22" text-anchor="middle" font-size="14">{title}</text>',
        f'<line x1="{left}" y1="{H - bottom}" x2="{W - right}" y2="{H - bottom}" stroke="black"/>',
        f'<line x1="{left}" y1="{top}" x2="{left}" y2="{H - bottom}" stroke="black"/>',
        f'<text x="{W / 2}" y="{H - 15}" text-anchor="middle">configurations N</text>',
        f'<text x="18" y="{(top + H - bottom) / 2}" text-anchor="middle" '
        f'transform="rotate(-90 18 {(top + H - bottom) / 2})">held-out error against the truth, RMS ({unit})</text>',
    ]
    for n in ns:
        out.append(f'<text x="{x(n)}" y="{H - bottom + 16}" text-anchor="middle">{n}</text>')
    for k in range(int(hi / step + 0.5) + 1):
        e = step * k
        out.append(f'<line x1="{left - 4}" y1="{y(e)}" x2="{left}" y2="{y(e)}" stroke="black"/>')
        out.append(f'<text x="{left - 6}" y="{y(e) + 4}" text-anchor="end">{e:.3g}</text>')
    if "random" in errors:  # the goal: random configurations at the largest N
        most = max(errors["random"])
        e = float(np.mean(errors["random"][most]))
        out.append(f'<line x1="{left}" y1="{y(e)}" x2="{W - right}" y2="{y(e)}" stroke="#888" stroke-dasharray="5 4"/>')
        out.append(f'<text x="{W - right - 4}" y="{y(e) - 5}" text-anchor="end" fill="#555">random, N = {most}</text>')
    for k, (method, per_n) in enumerate(errors.items()):
        colour = COLOURS[method]
        points = [(x(n), y(float(np.mean(v)))) for n, v in sorted(per_n.items())]
        out.append(
            f'<polyline fill="none" stroke="{colour}" stroke-width="2" '
            f'points="{" ".join(f"{a:.1f},{b:.1f}" for a, b in points)}"/>'
        )
        if expected is not None:
            dashed = [
                (x(n), y(float(np.mean(v)))) for n, v in sorted(expected[method].items()) if np.all(np.isfinite(v))
            ]
            out.append(
                f'<polyline fill="none" stroke="{colour}" stroke-width="1" stroke-dasharray="2 3" '
                f'points="{" ".join(f"{a:.1f},{b:.1f}" for a, b in dashed)}"/>'
            )
        for n, v in sorted(per_n.items()):
            m, s = float(np.mean(v)), float(np.std(v))
            out.append(f'<line x1="{x(n)}" y1="{y(m - s)}" x2="{x(n)}" y2="{y(m + s)}" stroke="{colour}"/>')
            out.append(f'<circle cx="{x(n)}" cy="{y(m)}" r="3" fill="{colour}"/>')
            if m > hi:
                out.append(
                    f'<text x="{x(n) + 6}" y="{y(m) + 12}" fill="{colour}">{m:.3g} +- {s:.3g} (off the scale)</text>'
                )
        ly = top + 10 + 18 * k
        out.append(f'<line x1="{W - 210}" y1="{ly}" x2="{W - 185}" y2="{ly}" stroke="{colour}" stroke-width="2"/>')
        out.append(f'<text x="{W - 180}" y="{ly + 4}">{METHODS[method]}</text>')
    if expected is not None:
        ly = top + 10 + 18 * len(errors)
        out.append(f'<line x1="{W - 210}" y1="{ly}" x2="{W - 185}" y2="{ly}" stroke="#555" stroke-dasharray="2 3"/>')
        out.append(f'<text x="{W - 180}" y="{ly + 4}">expected RMS (noise model)</text>')
    out.append("</svg>")
    with open(path, "w") as f:
        f.write("\n".join(out) + "\n")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--robot", default="robonaut-a")
    parser.add_argument("--mode", default="full")
    parser.add_argument("--counts", type=int, nargs="+", default=[16, 24, 32, 48, 67])
    parser.add_argument("--seeds", type=int, default=5)
    parser.add_argument("--methods", nargs="+", default=list(METHODS), choices=list(METHODS))
    parser.add_argument("--svg", help="also write the curve as an SVG file")
    parser.add_argument("--ymax", type=float, help="the SVG's error axis ends here (larger values are labelled)")
    parser.add_argument(
        "--json", help="also write every seed's figures as JSON ({errors|expected: {method: {N: [values]}}})"
    )
    args = parser.parse_args()
    errors, expected = run(args)
    if args.json:
        with open(args.json, "w") as f:
            json.dump({"errors": errors, "expected": expected}, f, indent=1)
    if args.svg:
        profile = load_profile(args.robot)
        unit = profile.sensors[profile.data.sensor].unit
        title = f"{args.robot} {args.mode}: planned vs random configurations"
        svg(errors, title, unit, args.svg, args.ymax, expected)
        print(f"wrote {args.svg}")


if __name__ == "__main__":
    main()
