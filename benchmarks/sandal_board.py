"""Sandal-board rendering and detection on one simulated NAO session (the paper's 144 frames).

    .venv/bin/python benchmarks/sandal_board.py [--seed 0]

Renders what the lower camera sees in the 24 stances x 3 head postures per leg (true parameters),
sharp and realistic (blur, noise, uneven light), detects the 24 vertices with the prediction of the
nominal (uncalibrated) parameters, a few degrees off the truth, and prints the corner errors against
the exact projections, the detection and rendering times, the detection rate with the rejections by
reason, and the rate by how obliquely the board is seen. Also the rate without a prediction (the CLI).
"""

from __future__ import annotations

import argparse
import itertools
import statistics
import time
from collections import Counter

import numpy as np

from calib_core import SimulatedRobot, load_profile
from calib_core.vision.sandal_board import board_corners, detect_board, render_board_image

OBLIQUITY_BINS_DEG = (70.0, 80.0, 83.0, 85.0, 86.0, 90.0)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seed", type=int, default=0, help="the simulated session")
    args = parser.parse_args()

    profile = load_profile("nao")
    truth, nominal = profile.true_params(), profile.nominal()
    q, targets = SimulatedRobot.from_profile(profile, seed=args.seed).configurations()
    rng = np.random.default_rng(args.seed)
    predicted = [board_corners(profile, nominal, q[n], targets[n]) for n in range(len(q))]

    images: dict[str, list[np.ndarray]] = {"sharp": [], "realistic": []}
    render_ms: dict[str, list[float]] = {"sharp": [], "realistic": []}
    true_px, obliquity_deg = [], []
    for n in range(len(q)):
        for kind, effects in (("sharp", {"blur_px": 0.0, "noise": 0.0, "light": 0.0}), ("realistic", {})):
            start = time.perf_counter()
            board = render_board_image(profile, truth, q[n], targets[n], rng, **effects)
            render_ms[kind].append(1e3 * (time.perf_counter() - start))
            images[kind].append(board.image)
        true_px.append(board.corners_true)
        obliquity_deg.append(board.obliquity_deg)
    obliquity = np.array(obliquity_deg)
    grid = np.array(true_px).reshape(len(q), 4, 6, 2)
    spacing_px = np.linalg.norm(np.diff(grid, axis=2), axis=3).min(axis=(1, 2))
    prediction_px = np.mean([np.linalg.norm(p - t, axis=1).mean() for p, t in zip(predicted, true_px, strict=True)])

    print(f"NAO sandal boards, session seed {args.seed}: {len(q)} frames (24 stances x 3 head postures per leg)")
    print(
        f"  seen at {obliquity.min():.1f}-{obliquity.max():.1f} deg from the sole's normal (median "
        f"{np.median(obliquity):.1f}); closest vertices {spacing_px.min():.1f}-{spacing_px.max():.1f} px apart "
        f"(median {np.median(spacing_px):.1f}); the nominal prediction is {prediction_px:.1f} px off on average"
    )
    for kind in images:
        print(f"  rendering ({kind}): median {statistics.median(render_ms[kind]):.0f} ms per 640 x 480 image")

    for kind in images:
        detect_ms, reasons, errors, wrong, quality = [], Counter(), [], 0, []
        found = np.zeros(len(q), bool)
        for n, image in enumerate(images[kind]):
            start = time.perf_counter()
            detection = detect_board(image, predicted=predicted[n])
            detect_ms.append(1e3 * (time.perf_counter() - start))
            reasons[detection.reason] += 1
            if detection.found:
                found[n] = True
                error = np.linalg.norm(detection.corners - true_px[n], axis=1)
                wrong += bool(error.mean() > 10.0)
                errors.append(error)
                quality.append((detection.residual_px, np.sqrt((error**2).mean())))
        e = np.concatenate(errors)
        residual, rms = np.array(quality).T
        print(f"\n{kind} images, detection with the nominal prediction:")
        print(f"  detected {found.sum()}/{len(q)} ({100 * found.mean():.0f}%), wrong vertex identities: {wrong}")
        print("  rejections: " + (", ".join(f"{r} {c}" for r, c in reasons.most_common() if r != "ok") or "none"))
        print(f"  corner error vs truth: RMS {np.sqrt((e**2).mean()):.3f} px, max {e.max():.3f} px (n={len(e)})")
        print(
            f"  homography residual per frame: median {np.median(residual):.3f} px; its correlation with the "
            f"frame's true RMS error {np.corrcoef(residual, rms)[0, 1]:.2f}"
        )
        print(
            f"  time per image: median {statistics.median(detect_ms):.1f} ms (target <= 20), "
            f"mean {statistics.fmean(detect_ms):.1f}, 90% {np.percentile(detect_ms, 90):.1f}, max {max(detect_ms):.0f}"
        )
        rates, accuracy = [], []
        frame_rms = np.full(len(q), np.nan)
        frame_rms[found] = [np.sqrt((err**2).mean()) for err in errors]
        for lo, hi in itertools.pairwise(OBLIQUITY_BINS_DEG):
            inside = (obliquity >= lo) & (obliquity < hi)
            rates.append(f"{lo:.0f}-{hi:.0f} deg {found[inside].sum()}/{inside.sum()}")
            if (inside & found).any():
                accuracy.append(f"{lo:.0f}-{hi:.0f} deg {np.sqrt(np.mean(frame_rms[inside & found] ** 2)):.3f} px")
        print("  detected by obliquity: " + ", ".join(rates))
        print("  corner RMS by obliquity: " + ", ".join(accuracy))

    no_prediction_ms, reasons = [], Counter()
    for image in images["realistic"]:
        start = time.perf_counter()
        reasons[detect_board(image).reason] += 1
        no_prediction_ms.append(1e3 * (time.perf_counter() - start))
    print("\nrealistic images without a prediction (the CLI):")
    print(f"  detected {reasons['ok']}/{len(q)}; " + ", ".join(f"{r} {c}" for r, c in reasons.most_common()))
    print(f"  time per image: median {statistics.median(no_prediction_ms):.1f} ms")


if __name__ == "__main__":
    main()
