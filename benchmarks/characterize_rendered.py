"""Paper section 5 end to end on rendered captures: calibrate, then characterize.

    .venv/bin/python benchmarks/characterize_rendered.py            # full: Z_in 0..80 step 4, 30 repeats
    .venv/bin/python benchmarks/characterize_rendered.py --repeats 5 --step 8   # quicker

1. Render (virtual rig, realistic 8-bit: 1.5 grey levels noise, defocus, 640x480,
   500 mm field) a reference and a 40 mm master block on the paper's true rig
   (L = 1022 mm, alpha = 0.332 rad).
2. Calibrate from the paper's rough start (L0 = 1080 mm, alpha0 = 0.4871 rad) with the
   least-squares method and with the paper's method (delta_z = 0.025 mm, m^ = 0.0001).
3. Render the stage series (a plane at each Z_in, ``repeats`` captures each, fresh noise),
   measure every capture with the lsq-calibrated rig against the kept reference, and
   characterize: in-out slopes per test point, mean error and sigma versus Z_in, overall.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from metrology.core.calibrate import MasterCapture, calibrate_lsq, calibrate_paper
from metrology.core.characterize import characterize
from metrology.core.geometry.crossed_axes import PAPER_RIG
from metrology.core.measure import MeasureOptions, measure, prepare_reference
from metrology.core.scenes import make_scene
from metrology.core.simulate import SimulationOptions, render_series, render_stack


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--step", type=float, default=4.0, help="Z_in step, mm (default 4)")
    parser.add_argument("--top", type=float, default=80.0, help="largest Z_in, mm (default 80)")
    parser.add_argument("--repeats", type=int, default=30)
    parser.add_argument("--json", help="write the characterization report here")
    args = parser.parse_args()

    truth = PAPER_RIG
    rough = truth.with_parameters(L_mm=1080.0, alpha_rad=0.4871)
    simulation = SimulationOptions.realistic_8bit(seed=2026)
    start = time.perf_counter()
    reference_stack = render_stack(truth, make_scene("reference", truth), simulation).images
    master_stack = render_stack(truth, make_scene("block", truth, top_mm=40.0), simulation.with_changes(seed=7)).images
    options = MeasureOptions(gray_only=False)
    reference = prepare_reference(rough, reference_stack, None, options)
    master_codes = measure(rough, master_stack, reference=reference, options=options).codes
    master = MasterCapture(reference.codes, master_codes, 40.0)

    print("calibration from L0 = 1080 mm, alpha0 = 0.4871 rad (truth 1022 mm, 0.332 rad)")
    lsq = calibrate_lsq(rough, master)
    paper = calibrate_paper(rough, reference.codes, master_codes, 40.0, delta_z_mm=0.025, m_hat=1e-4)
    for result in (lsq, paper):
        report = result.to_dict()
        print(
            f"  {report['method']:6s} iterations {report['iterations']:3d}  converged {report['converged']}  "
            f"L - L_true = {result.L_mm - truth.L_mm:+.3f} mm  "
            f"alpha - alpha_true = {result.alpha_rad - truth.alpha_rad:+.5f} rad"
        )

    rig = lsq.rig
    kept = prepare_reference(rig, reference_stack, None, options)
    positions = list(np.arange(0.0, args.top + args.step / 2, args.step))

    def heights():
        for z_in, repeat, rendered in render_series(truth, positions, args.repeats, simulation):
            yield z_in, repeat, measure(rig, rendered.images, reference=kept, options=options).z_mm

    result = characterize(rig, heights())
    elapsed = time.perf_counter() - start
    slopes = np.array([p["slope"] for p in result["test_points"]])
    mean_um = np.array(result["mean_error_mm"]) * 1e3
    std_um = np.array(result["std_error_mm"]) * 1e3
    overall = result["overall"]
    print(
        f"\ncharacterization: {len(positions)} positions x {args.repeats} repeats, "
        f"{len(slopes)} test points (5x5 px) at the middle row, lsq-calibrated rig"
    )
    print(f"  in-out slopes: {slopes.min():.5f} .. {slopes.max():.5f} (paper: 1 +- 0.0001)")
    print(
        f"  mean error per Z_in: {mean_um.min():+.1f} .. {mean_um.max():+.1f} um "
        f"(max |.| {np.abs(mean_um).max():.1f} um)"
    )
    print(f"  sigma per Z_in: {std_um.min():.1f} .. {std_um.max():.1f} um")
    print(
        f"  overall: mean error {overall['mean_error_mm'] * 1e3:+.1f} um, "
        f"variability {overall['std_error_mm'] * 1e3:.1f} um, "
        f"{overall['error_pct_fs']:.3f} % of {overall['full_scale_mm']:.0f} mm full scale "
        "(paper: 40 um +- 35 um, 0.06 %)"
    )
    print(f"  elapsed {elapsed:.0f} s")
    if args.json:
        Path(args.json).write_text(json.dumps(result, indent=2))


if __name__ == "__main__":
    main()
